"""The streaming interface every motion detector shares, and the checks on the frames fed to it."""

from __future__ import annotations

from typing import Protocol

import cv2
import numpy as np


class MotionDetector(Protocol):
    """Feed frames one at a time; get a binary motion mask once enough frames have been seen.

    `apply(frame)` takes an RGB (H, W, 3) or grey (H, W) uint8 frame and returns an (H, W) uint8 mask
    (255 = moving, 0 = still) or None while the detector still waits for frames. The mask refers to the
    frame fed `latency` calls earlier: 0-based index `mask_index` (the five-frame difference centred on
    frame t needs frames t+1 and t+2, so its latency is 2). `reset()` forgets everything, as if new.
    """

    latency: int

    def apply(self, frame: np.ndarray) -> np.ndarray | None: ...

    def reset(self) -> None: ...

    @property
    def mask_index(self) -> int: ...


def to_grey(frame: np.ndarray) -> np.ndarray:
    """(H, W) uint8 luminance of an RGB (H, W, 3) or grey (H, W) / (H, W, 1) uint8 frame."""
    if frame.ndim == 3 and frame.shape[2] == 3:
        return cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
    return frame.reshape(frame.shape[0], frame.shape[1])


def match_exposure(grey: np.ndarray, mean: float) -> np.ndarray:
    """`grey` (uint8) scaled so its mean grey level becomes `mean` (saturating at 255).

    Undoes a change of exposure or gain, which multiplies every pixel: the adaptive threshold of eq. 17
    absorbs an added light level, not a doubled one.
    """
    return scale_exposure(grey, cv2.mean(grey)[0], mean)


def scale_exposure(grey: np.ndarray, current: float, target: float) -> np.ndarray:
    """`grey` (uint8, mean grey level `current`) scaled by target / current, saturating at 255.

    A black frame, or a ratio within 1 % of one (a change of at most 2.5 grey levels), is returned as it is.
    """
    if current <= 0 or target <= 0 or abs(target / current - 1) < 0.01:
        return grey
    return cv2.convertScaleAbs(grey, alpha=target / current)


class FrameGuard:
    """Counts frames and rejects input a detector cannot use, naming the 0-based frame index.

    Accepted: non-empty uint8 arrays of shape (H, W), (H, W, 1) or (H, W, 3), all of the first frame's shape.
    """

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.count = 0
        self.shape: tuple[int, ...] | None = None

    def check(self, frame: object) -> np.ndarray:
        """Return `frame` unchanged if usable, else raise ValueError naming its index; counts the frame."""
        index = self.count
        if not isinstance(frame, np.ndarray):
            raise ValueError(f"frame {index}: expected a numpy array, got {type(frame).__name__}")
        if frame.size == 0:
            raise ValueError(f"frame {index}: empty frame of shape {frame.shape}")
        if frame.dtype.kind == "f" and np.isnan(frame).any():
            raise ValueError(f"frame {index}: contains NaN (dtype {frame.dtype}); expected uint8 pixels")
        if frame.dtype != np.uint8:
            raise ValueError(f"frame {index}: dtype {frame.dtype}, expected uint8")
        if frame.ndim not in (2, 3) or (frame.ndim == 3 and frame.shape[2] not in (1, 3)):
            raise ValueError(f"frame {index}: shape {frame.shape}, expected (H, W), (H, W, 1) or (H, W, 3)")
        if self.shape is None:
            self.shape = frame.shape
        elif frame.shape != self.shape:
            raise ValueError(
                f"frame {index}: shape {frame.shape} differs from the first frame's {self.shape} "
                "(size and channel count must stay the same; call reset() for a new sequence)"
            )
        self.count += 1
        return frame
