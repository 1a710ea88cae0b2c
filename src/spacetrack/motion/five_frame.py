"""The paper's five-frame difference (eqs. 16-19, Fig. 7), centred on frame t; latency 2 frames."""

from __future__ import annotations

import cv2
import numpy as np

from spacetrack.motion.difference import FrameDifference


class FiveFrameDifference(FrameDifference):
    """M_t = (Y_{t-2} and Y_{t-1}) or (Y_{t+1} and Y_{t+2}), Y_k the thresholded |I_t - I_k|.

    'And' within each side removes the ghost a target leaves where it was; 'or' across sides fills the
    holes one side leaves inside a slow target. Each Y_k has its own adaptive threshold (eq. 17).
    """

    span = 5
    latency = 2

    def _combine(self, frames: list[np.ndarray]) -> np.ndarray:
        centre = frames[2]
        y = [self._moving(centre, frames[k]) for k in (0, 1, 3, 4)]
        return cv2.bitwise_or(cv2.bitwise_and(y[0], y[1]), cv2.bitwise_and(y[2], y[3]))
