"""A dim synthetic space frame: near-black noisy sky, stars, and dim grey and coloured targets."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

SKY = 8.0
NOISE_SIGMA = 3.0
# (centre row, centre col, radius, RGB): all well under 40 grey levels, like the paper's dark scenes.
TARGETS = [
    (60, 80, 12, (28, 28, 28)),
    (150, 210, 8, (30, 24, 16)),
    (190, 60, 6, (22, 26, 34)),
    (100, 260, 16, (24, 24, 24)),
]


@dataclass
class DimFrame:
    rgb: np.ndarray  # RGB uint8 (H, W, 3)
    target: np.ndarray  # bool (H, W): target pixels
    background: np.ndarray  # bool (H, W): pixels at least 6 px away from every target


def render_dim_frame(height: int = 240, width: int = 320, seed: int = 0) -> DimFrame:
    rng = np.random.default_rng(seed)
    img = SKY + rng.normal(0.0, NOISE_SIGMA, (height, width, 3))
    rows, cols = np.mgrid[:height, :width]
    target = np.zeros((height, width), bool)
    near = np.zeros((height, width), bool)
    for r0, c0, radius, colour in TARGETS:
        d2 = (rows - r0) ** 2 + (cols - c0) ** 2
        inside = d2 <= radius**2
        img[inside] += np.asarray(colour, float) - SKY
        target |= inside
        near |= d2 <= (radius + 6) ** 2
    stars = rng.integers(0, [height, width], size=(15, 2))
    img[stars[:, 0], stars[:, 1]] = 200.0
    background = ~near
    background[stars[:, 0], stars[:, 1]] = False
    return DimFrame(np.clip(np.rint(img), 0, 255).astype(np.uint8), target, background)


def contrast(rgb: np.ndarray, target: np.ndarray, background: np.ndarray) -> float:
    """(mean target V - mean background V) / std of background V, with V = max(R, G, B)."""
    v = rgb.max(axis=2).astype(np.float64)
    return float((v[target].mean() - v[background].mean()) / v[background].std())


@pytest.fixture(scope="session")
def dim_frame() -> DimFrame:
    return render_dim_frame()


@pytest.fixture(scope="session")
def make_dim_frame():
    """`render_dim_frame(height, width, seed)`, for tests that need other noise draws."""
    return render_dim_frame


@pytest.fixture(scope="session")
def frame_contrast():
    """`contrast(rgb, target, background)`."""
    return contrast
