"""What every enhancer shares: the input check and the identity enhancer (`enhance=none`)."""

from __future__ import annotations

import numpy as np


def check_rgb(rgb: np.ndarray) -> np.ndarray:
    """Return `rgb` if it is a non-empty RGB uint8 image of shape (H, W, 3), else raise ValueError."""
    if not isinstance(rgb, np.ndarray):
        raise ValueError(f"expected an RGB uint8 numpy array of shape (H, W, 3), got {type(rgb).__name__}")
    if rgb.dtype != np.uint8:
        raise ValueError(f"expected an RGB uint8 image, got dtype {rgb.dtype} (shape {rgb.shape})")
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"expected an RGB image of shape (H, W, 3), got shape {rgb.shape}")
    if rgb.shape[0] == 0 or rgb.shape[1] == 0:
        raise ValueError(f"expected a non-empty RGB image, got shape {rgb.shape}")
    return rgb


class NoEnhancement:
    """The identity: returns its RGB uint8 (H, W, 3) input unchanged (the same array, not a copy)."""

    name = "none"

    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        return check_rgb(rgb)

    def __repr__(self) -> str:
        return "NoEnhancement()"
