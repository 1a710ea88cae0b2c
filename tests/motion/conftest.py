"""Tiny hand-built scenes whose motion masks are known exactly."""

from __future__ import annotations

import numpy as np
import pytest


def render_scene(
    num_frames: int,
    *,
    shape: tuple[int, int] = (64, 96),
    size: int = 8,
    start: tuple[int, int] = (10, 20),
    velocity: tuple[int, int] = (10, 0),
    stop_at: int | None = None,
    stars: tuple[tuple[int, int], ...] = (),
    flash_at: int | None = None,
    flash: int = 60,
    noise: float = 2.0,
    seed: int = 0,
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Grey frames of a bright square moving over a dark field, and its true (H, W) bool masks.

    The square (value 200, `size` px) starts with its top-left corner at `start` (x, y) and moves by
    `velocity` (px per frame) until frame `stop_at`; `stars` are static 1-pixel points of value 230;
    frame `flash_at` is brighter everywhere by `flash` grey levels.
    """
    rng = np.random.default_rng(seed)
    frames, masks = [], []
    for t in range(num_frames):
        steps = t if stop_at is None else min(t, stop_at)
        x, y = start[0] + velocity[0] * steps, start[1] + velocity[1] * steps
        field = 10.0 + rng.normal(0.0, noise, shape)
        for sx, sy in stars:
            field[sy, sx] = 230.0
        mask = np.zeros(shape, dtype=bool)
        mask[y : y + size, x : x + size] = True
        field[mask] = 200.0
        if t == flash_at:
            field += flash
        frames.append(np.clip(field, 0, 255).astype(np.uint8))
        masks.append(mask)
    return frames, masks


@pytest.fixture
def scene():
    return render_scene


def run_detector(detector, frames: list[np.ndarray]) -> dict[int, np.ndarray]:
    """{frame index: bool mask} of every mask `detector` returns on `frames`."""
    out = {}
    for frame in frames:
        mask = detector.apply(frame)
        if mask is not None:
            assert mask.shape == frame.shape[:2] and mask.dtype == np.uint8
            out[detector.mask_index] = mask > 0
    return out


@pytest.fixture
def run():
    return run_detector
