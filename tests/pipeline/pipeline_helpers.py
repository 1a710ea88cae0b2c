"""Pipeline test helpers: the real track config pointed at a dataset and a temporary folder."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from spacetrack.config import compose_config


def track_config(dataset: Path, tmp_path: Path, *overrides: str) -> DictConfig:
    """conf/track.yaml on the smoke dataset with outputs and cache under `tmp_path`, no MLflow."""
    base = [
        "data=smoke",
        f"data_root={dataset.parent}",
        "logger=none",
        f"output_dir={tmp_path / 'out'}",
        f"cache.dir={tmp_path / 'cache'}",
        "progress=false",
    ]
    return compose_config("track", base + list(overrides))
