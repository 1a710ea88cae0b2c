"""OpenCV's MOG2 and KNN background subtractors behind the same streaming interface (the peers)."""

from __future__ import annotations

from abc import ABC, abstractmethod

import cv2
import numpy as np

from spacetrack.motion.frames import FrameGuard, to_grey


class _OpenCVSubtractor(ABC):
    latency = 0

    def __init__(self, *, grey: bool) -> None:
        self.grey = grey
        self._guard = FrameGuard()
        self.reset()

    @abstractmethod
    def _create(self) -> cv2.BackgroundSubtractor:
        """A fresh OpenCV subtractor with this object's settings."""

    def reset(self) -> None:
        self._guard.reset()
        self._subtractor = self._create()

    @property
    def mask_index(self) -> int:
        return self._guard.count - 1

    def apply(self, frame: np.ndarray) -> np.ndarray | None:
        frame = self._guard.check(frame)
        # Channel order does not matter to these per-pixel models, so RGB is passed without conversion.
        image = to_grey(frame) if self.grey else frame
        raw = self._subtractor.apply(image)
        # Shadow pixels (127, only with detect_shadows) are not motion.
        _, mask = cv2.threshold(raw, 127, 255, cv2.THRESH_BINARY)
        return mask


class MOG2(_OpenCVSubtractor):
    """Gaussian-mixture background subtraction (cv2.createBackgroundSubtractorMOG2), latency 0.

    Args:
        history: frames that shape the model.
        var_threshold: squared Mahalanobis distance above which a pixel is foreground.
        detect_shadows: let OpenCV label shadows (they are then dropped from the mask).
        grey: feed the grey image instead of the colour frame.
    """

    def __init__(
        self,
        *,
        history: int = 500,
        var_threshold: float = 16.0,
        detect_shadows: bool = False,
        grey: bool = False,
    ) -> None:
        self.history = history
        self.var_threshold = var_threshold
        self.detect_shadows = detect_shadows
        super().__init__(grey=grey)

    def _create(self) -> cv2.BackgroundSubtractor:
        return cv2.createBackgroundSubtractorMOG2(self.history, self.var_threshold, self.detect_shadows)


class KNN(_OpenCVSubtractor):
    """K-nearest-neighbour background subtraction (cv2.createBackgroundSubtractorKNN), latency 0.

    Args:
        history: frames that shape the model.
        dist2_threshold: squared distance to the nearest samples above which a pixel is foreground.
        detect_shadows: let OpenCV label shadows (they are then dropped from the mask).
        grey: feed the grey image instead of the colour frame.
    """

    def __init__(
        self,
        *,
        history: int = 500,
        dist2_threshold: float = 400.0,
        detect_shadows: bool = False,
        grey: bool = False,
    ) -> None:
        self.history = history
        self.dist2_threshold = dist2_threshold
        self.detect_shadows = detect_shadows
        super().__init__(grey=grey)

    def _create(self) -> cv2.BackgroundSubtractor:
        return cv2.createBackgroundSubtractorKNN(self.history, self.dist2_threshold, self.detect_shadows)
