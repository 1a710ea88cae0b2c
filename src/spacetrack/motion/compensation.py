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
        crop: correlate only the central crop x crop pixels (a power of two keeps the FFT fast; stars
            fill any part of the sky); 0 uses the whole frame.
        min_response: phase-correlation peaks weaker than this (a featureless frame) count as no motion.

    Full resolution on purpose: shrinking the frames first costs half-pixel errors that add up.
    """

    def __init__(self, *, crop: int = 256, min_response: float = 0.05) -> None:
        if crop < 0:
            raise ValueError(f"crop must be >= 0 pixels, got {crop}")
        self.crop = crop
        self.min_response = min_response
        self.reset()

    def reset(self) -> None:
        self._previous: np.ndarray | None = None
        self._window: np.ndarray | None = None
        self._position = np.zeros(2)

    def update(self, grey: np.ndarray) -> tuple[int, int]:
        """Feed the next (H, W) uint8 frame; return its whole-pixel offset (x, y) from the first frame."""
        h, w = grey.shape
        ch, cw = (min(h, self.crop), min(w, self.crop)) if self.crop else (h, w)
        top, left = (h - ch) // 2, (w - cw) // 2
        patch = grey[top : top + ch, left : left + cw].astype(np.float32)
        if self._previous is not None:
            if self._window is None:
                self._window = cv2.createHanningWindow((cw, ch), cv2.CV_32F)
            (dx, dy), response = cv2.phaseCorrelate(self._previous, patch, self._window)
            if np.isfinite(response) and response >= self.min_response:
                self._position += (dx, dy)
        self._previous = patch
        return int(round(self._position[0])), int(round(self._position[1]))
