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


@pytest.fixture
def tiny_dataset(tmp_path) -> Path:
    """A hand-made detector dataset of a few frames (see `detector_helpers.write_tiny_dataset`)."""
    from detector_helpers import write_tiny_dataset

    return write_tiny_dataset(tmp_path / "tiny")


@pytest.fixture
def one_torch_thread():
    """torch on one CPU thread for the test, then as it was: on a crowded machine tracing or building a
    model on two threads can be many times slower than on one."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
