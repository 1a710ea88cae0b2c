"""Inter-frame differencing (paper eq. 1 and Fig. 4) with the light-adaptive threshold of eq. 17.

`FrameDifference` keeps the last few grey frames and leaves the combination of their differences to a
subclass: `TwoFrameDifference` (eq. 1), `ThreeFrameDifference` (Fig. 4) and, in `five_frame`, the paper's
five-frame difference. With `compensate`, frames are first brought into one pixel grid, that of the frame
the mask refers to to within half a pixel (see `compensation`), so a slewing camera does not turn the star
field into motion.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections import deque

import cv2
import numpy as np

from spacetrack.motion.compensation import scene_shift_for, shift_image, warp_shift
from spacetrack.motion.frames import FrameGuard, scale_exposure, to_grey


def binarise(diff: np.ndarray, *, alpha: float, threshold: float) -> np.ndarray:
    """Moving pixels of an absolute grey difference image: uint8 255 where diff >= T_k, else 0.

    T_k = alpha * mean(diff) + threshold (eq. 17). The mean term lifts the threshold when the whole frame
    brightens or darkens at once, so a global flash of light is not motion. Eq. 16 in the paper writes the
    comparison the wrong way round; moving pixels are those at or above the threshold.
    """
    level = alpha * cv2.mean(diff)[0] + threshold
    _, mask = cv2.threshold(diff, math.ceil(level) - 1, 255, cv2.THRESH_BINARY)
    return mask


class FrameDifference(ABC):
    """Base of the differencing detectors: frame checks, history, alignment and latency.

    Args:
        alpha: weight of the mean absolute difference in the adaptive threshold (eq. 17), unitless.
        threshold: fixed part T of the threshold, grey levels (0-255).
        compensate: register frames against global camera motion before differencing: true, false, or
            "auto" (only once the scene is found to move; see `compensation.SceneShift`'s `probe_every`).
        match_exposure: scale every frame of the window to the mean grey level of the frame the mask
            refers to, so an exposure step (all pixels times a gain) is not motion.
    """

    span = 2  # frames in the window
    latency = 0  # frames between the newest frame and the one the mask refers to

    def __init__(
        self,
        *,
        alpha: float = 1.0,
        threshold: float = 20.0,
        compensate: bool | str = False,
        match_exposure: bool = False,
    ) -> None:
        if threshold <= 0:
            raise ValueError(f"threshold must be > 0 grey levels, got {threshold}")
        if alpha < 0:
            raise ValueError(f"alpha must be >= 0, got {alpha}")
        self.alpha = alpha
        self.threshold = threshold
        self.compensate = compensate
        self.match_exposure = match_exposure
        self._guard = FrameGuard()
        self.scene_shift = scene_shift_for(compensate)  # the fusion hands its ViBe this one
        # (grey frame, scene offset (x, y), mean grey level) of the last `span` frames
        self._history: deque[tuple[np.ndarray, tuple[int, int], float]] = deque(maxlen=self.span)

    def reset(self) -> None:
        self._guard.reset()
        self.scene_shift.reset()
        self._history.clear()

    @property
    def mask_index(self) -> int:
        """0-based index of the frame the latest mask refers to."""
        return self._guard.count - 1 - self.latency

    def apply(self, frame: np.ndarray) -> np.ndarray | None:
        grey = to_grey(self._guard.check(frame))
        offset = (0, 0)
        if self.compensate:
            x, y = self.scene_shift.update(grey, self._guard.count - 1)
            offset = (round(x), round(y))
            # Resample once, onto the whole-pixel grid of the scene (at most half a pixel): from then on
            # frames align by whole pixels, without interpolating the history again for every mask.
            grey = warp_shift(grey, offset[0] - x, offset[1] - y, grey)
        self._history.append((grey, offset, cv2.mean(grey)[0] if self.match_exposure else 0.0))
        if len(self._history) < self.span:
            return None
        centre, (cx, cy), level = self._history[self.span - 1 - self.latency]
        aligned = []
        for g, (ox, oy), mean in self._history:
            if self.match_exposure:
                g = scale_exposure(g, mean, level)
            # Pixels that entered the view have no past: they take the centre frame's value (no change).
            aligned.append(shift_image(g, cx - ox, cy - oy, centre))
        return self._combine(aligned)

    def _moving(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Moving pixels of frame `a` against frame `b` (uint8 0/255)."""
        return binarise(cv2.absdiff(a, b), alpha=self.alpha, threshold=self.threshold)

    @abstractmethod
    def _combine(self, frames: list[np.ndarray]) -> np.ndarray:
        """Mask from the aligned window, oldest first; the mask refers to frames[span - 1 - latency]."""


class TwoFrameDifference(FrameDifference):
    """|I_t - I_{t-1}| thresholded (eq. 1); marks both the old and the new place ('bilateral thick outline')."""

    span = 2
    latency = 0

    def _combine(self, frames: list[np.ndarray]) -> np.ndarray:
        return self._moving(frames[1], frames[0])


class ThreeFrameDifference(FrameDifference):
    """Centred on I_{t-1}: both its differences to I_{t-2} and to I_t must be moving ('and', Fig. 4)."""

    span = 3
    latency = 1

    def _combine(self, frames: list[np.ndarray]) -> np.ndarray:
        return cv2.bitwise_and(self._moving(frames[1], frames[0]), self._moving(frames[1], frames[2]))
