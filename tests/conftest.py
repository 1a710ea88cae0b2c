"""Shared fixtures: compose the project's real Hydra configs, build the smoke dataset once per session."""

from __future__ import annotations

from pathlib import Path

import pytest

from spacetrack.config import compose_config


@pytest.fixture(scope="session")
def smoke_dataset(tmp_path_factory) -> Path:
    """data=smoke (9 sequences, one per scenario/fold, 48 frames at 320x240) rendered once for the session."""
    from spacetrack import build_data

    root = tmp_path_factory.mktemp("datasets")
    cfg = compose_config("build_data", ["data=smoke", "logger=none", f"data_root={root}", "progress=false"])
    build_data.run(cfg)
    return root / "space_smoke"
