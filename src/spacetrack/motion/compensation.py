"""Global motion compensation for a slewing camera: where has the whole scene moved since the first frame?

Beyond the paper. A camera that slews moves every star and static object in the image; differencing or a
background model then sees the star field as motion. `SceneShift` measures the translation between
consecutive frames by phase correlation (OpenCV) and accumulates it; the detectors bring their history into
the current frame's pixel grid with `shift_image` before comparing. Shifts are rounded to whole pixels so
that stored frames are moved, never resampled (interpolating a one-pixel star would itself look like change).
"""

from __future__ import annotations

import cv2
import numpy as np


def shift_image(image: np.ndarray, dx: int, dy: int, fill: np.ndarray, *, axis: int = 0) -> np.ndarray:
    """`image` with its content moved by (dx, dy) whole pixels; pixels that had no source are taken from `fill`.

    `image` has its rows and columns at axes `axis` and `axis + 1` (e.g. a stack of (N, H, W) samples with
    axis=1); `fill` broadcasts against `image`. Returns a new array (or `image` itself for a zero shift).
    """
    if dx == 0 and dy == 0:
        return image
    h, w = image.shape[axis], image.shape[axis + 1]
    out = np.empty_like(image)
    out[...] = fill
    if abs(dx) >= w or abs(dy) >= h:
        return out
    lead = (slice(None),) * axis
    dst = lead + (slice(max(dy, 0), h + min(dy, 0)), slice(max(dx, 0), w + min(dx, 0)))
    src = lead + (slice(max(-dy, 0), h + min(-dy, 0)), slice(max(-dx, 0), w + min(-dx, 0)))
    out[dst] = image[src]
    return out


class SceneShift:
    """Cumulative scene displacement (pixels, x right and y down) of each frame relative to the first.

    Args:
        downscale: correlate frames shrunk by this integer factor (faster; the shift is scaled back).
        min_response: phase-correlation peaks weaker than this (a featureless frame) count as no motion.
    """

    def __init__(self, *, downscale: int = 2, min_response: float = 0.05) -> None:
        if downscale < 1:
            raise ValueError(f"downscale must be >= 1, got {downscale}")
        self.downscale = downscale
        self.min_response = min_response
        self.reset()

    def reset(self) -> None:
        self._previous: np.ndarray | None = None
        self._window: np.ndarray | None = None
        self._position = np.zeros(2)

    def update(self, grey: np.ndarray) -> tuple[int, int]:
        """Feed the next (H, W) uint8 frame; return its whole-pixel offset (x, y) from the first frame."""
        small = grey.astype(np.float32)
        if self.downscale > 1:
            size = (grey.shape[1] // self.downscale, grey.shape[0] // self.downscale)
            small = cv2.resize(small, size, interpolation=cv2.INTER_AREA)
        if self._previous is not None:
            if self._window is None:
                self._window = cv2.createHanningWindow(small.shape[::-1], cv2.CV_32F)
            (dx, dy), response = cv2.phaseCorrelate(self._previous, small, self._window)
            if np.isfinite(response) and response >= self.min_response:
                self._position += np.array([dx, dy]) * self.downscale
        self._previous = small
        return int(round(self._position[0])), int(round(self._position[1]))
