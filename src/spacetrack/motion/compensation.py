"""Global motion compensation for a slewing camera: where has the whole scene moved since the first frame?

Beyond the paper. A camera that slews moves every star and static object in the image; differencing or a
background model then sees the star field as motion. `SceneShift` measures the translation between
consecutive frames by phase correlation (OpenCV) on a grid of tiles and takes the median, so the few tiles
that a large moving target fills do not pull the estimate along with the target. The differencing
detectors resample each frame once onto the scene's whole-pixel grid (`warp_shift`, sub-pixel) and then
align their history by whole pixels (`shift_image`); ViBe moves its model by whole pixels, its
neighbourhood sampling absorbing the remaining fraction.
"""

from __future__ import annotations

import threading

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
    if abs(dx) >= w or abs(dy) >= h:
        out[...] = fill
        return out
    lead = (slice(None),) * axis
    dst = lead + (slice(max(dy, 0), h + min(dy, 0)), slice(max(dx, 0), w + min(dx, 0)))
    src = lead + (slice(max(-dy, 0), h + min(-dy, 0)), slice(max(-dx, 0), w + min(-dx, 0)))
    out[dst] = image[src]
    # only the strips that had no source take `fill` (one pass over the array, not two)
    fill = np.broadcast_to(np.asarray(fill, dtype=image.dtype), image.shape)
    rows = slice(0, dy) if dy > 0 else slice(h + dy, h)
    cols = slice(0, dx) if dx > 0 else slice(w + dx, w)
    if dy != 0:
        out[lead + (rows,)] = fill[lead + (rows,)]
    if dx != 0:
        out[lead + (slice(None), cols)] = fill[lead + (slice(None), cols)]
    return out


def warp_shift(image: np.ndarray, dx: float, dy: float, fill: np.ndarray) -> np.ndarray:
    """`image` (H, W) with its content moved by (dx, dy) pixels (bilinear); pixels without source from `fill`."""
    if dx == 0 and dy == 0:
        return image
    matrix = np.array([[1.0, 0.0, dx], [0.0, 1.0, dy]])
    size = (image.shape[1], image.shape[0])
    return cv2.warpAffine(image, matrix, size, dst=fill.copy(), borderMode=cv2.BORDER_TRANSPARENT)


class SceneShift:
    """Cumulative scene displacement (pixels, x right and y down) of each frame relative to the first.

    Args:
        tile: side of the square tiles (pixels; a power of two keeps the FFT fast) laid over the frame;
            each gives one shift estimate and the median of the confident ones is the frame's shift.
        min_response: tiles whose phase-correlation peak is weaker than this (no stars in them) abstain;
            with no confident tile the frame counts as still.
        min_step: a frame-to-frame shift shorter than this (pixels) counts as none. Tiles that a moving
            target fills bias each estimate by a few hundredths of a pixel, always the same way while the
            target moves on; summed over a still camera's frames that made the estimate wander by 1 to 5
            pixels in 150 frames of the renders, and ViBe's model with it. Slews slower than this go
            uncompensated (0: compensate any shift).

    Detectors fed the same frames can share one estimator (the fusion's two parts do): `update` with the
    caller's frame number measures each frame once and hands its offset to the next caller too.
    """

    def __init__(self, *, tile: int = 128, min_response: float = 0.05, min_step: float = 0.25) -> None:
        if tile < 8:
            raise ValueError(f"tile must be >= 8 pixels, got {tile}")
        if min_step < 0:
            raise ValueError(f"min_step must be >= 0 pixels, got {min_step}")
        self.tile = tile
        self.min_response = min_response
        self.min_step = min_step
        self._lock = threading.Lock()  # sharers may call from two threads (the fusion's `parallel`)
        self.reset()

    def reset(self) -> None:
        with self._lock:
            self._previous: np.ndarray | None = None
            self._window: np.ndarray | None = None
            self._position = np.zeros(2)
            self._frames = 0

    def update(self, grey: np.ndarray, frame: int | None = None) -> tuple[float, float]:
        """Feed the next (H, W) uint8 frame; return its offset (x, y) in pixels from the first frame.

        `frame`: the caller's 0-based number of this frame; a frame already measured is not measured
        again (its offset is returned), so sharers must feed the same frames in the same order.
        """
        with self._lock:
            if frame is not None and frame == self._frames - 1:
                return float(self._position[0]), float(self._position[1])
            if frame is not None and frame != self._frames:
                raise ValueError(f"frame {frame} given to a scene-shift estimator at frame {self._frames}")
            self._frames += 1
            return self._measure(grey)

    def _measure(self, grey: np.ndarray) -> tuple[float, float]:
        h, w = grey.shape
        side = min(self.tile, h, w)
        current = grey.astype(np.float32)
        if self._previous is not None:
            if self._window is None:
                self._window = cv2.createHanningWindow((side, side), cv2.CV_32F)
            shifts = []
            for top in range(0, h - side + 1, side):
                for left in range(0, w - side + 1, side):
                    window = (slice(top, top + side), slice(left, left + side))
                    (dx, dy), response = cv2.phaseCorrelate(
                        self._previous[window], current[window], self._window
                    )
                    if np.isfinite(response) and response >= self.min_response:
                        shifts.append((dx, dy))
            if shifts:
                step = np.median(np.array(shifts), axis=0)
                if np.hypot(*step) >= self.min_step:
                    self._position += step
        self._previous = current
        return float(self._position[0]), float(self._position[1])
