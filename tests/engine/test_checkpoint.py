"""`resume` means the same for both networks: null, auto or the path of a last.pt."""

from __future__ import annotations

from pathlib import Path

import pytest

from spacetrack.engine.checkpoint import resume_choice


def test_resume_is_null_auto_or_an_existing_checkpoint(tmp_path):
    assert resume_choice(None) is None
    assert resume_choice("auto") == "auto"
    last = tmp_path / "last.pt"
    last.write_bytes(b"x")
    assert resume_choice(str(last)) == Path(last)


@pytest.mark.parametrize("value", [True, False, 3])
def test_a_flag_or_number_is_refused_naming_the_value(value):
    with pytest.raises(
        ValueError, match=rf"resume must be null, auto or the path of a last\.pt, got {value!r}"
    ):
        resume_choice(value)


def test_a_missing_checkpoint_is_refused_naming_it(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"resume=.*nowhere/last\.pt: no such checkpoint"):
        resume_choice(str(tmp_path / "nowhere" / "last.pt"))
