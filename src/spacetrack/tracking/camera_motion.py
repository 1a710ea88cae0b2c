"""The camera's motion for the tracker: how far the scene moved in the image, frame by frame.

Measured by the motion stage's own estimator (`motion.compensation.SceneShift`: phase correlation on tiles,
the median of the confident ones) on the frames the tracker sees. The tracker moves its predictions by
each frame's shift and judges a track's motion in scene coordinates (`tracking.dynamic`).
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from spacetrack.motion.compensation import PROBE_EVERY, SceneShift

log = logging.getLogger(__name__)
MODES = (False, True, "auto")


class _CountedSceneShift(SceneShift):
    """A `SceneShift` that remembers whether its last measurement had any confident tile."""

    failed = False

    def _step(self, previous: np.ndarray, current: np.ndarray) -> tuple[np.ndarray, int]:
        step, tiles = super()._step(previous, current)
        self.failed = tiles == 0
        return step, tiles


class CameraMotion:
    """Scene shift per frame. mode: False (none: every shift is zero), True (measure every frame) or
    "auto" (probe the second frame, then every few frames, and measure every frame once the scene moves:
    a still camera's shifts stay exactly zero). A frame without texture to measure (no confident tile)
    counts as still, and the first such frame of a sequence is logged. `moving` tells whether any shift
    has been applied yet (the track-level decision then stops trusting the motion masks)."""

    def __init__(self, mode: bool | str, *, name: str = "tracker.camera_motion") -> None:
        if mode not in MODES:
            raise ValueError(f"{name} must be false, true or auto, got {mode!r}")
        self.mode = mode
        self._scene = (
            _CountedSceneShift(probe_every=PROBE_EVERY if mode == "auto" else 0, first_probe=True)
            if mode
            else None
        )
        self._offset = np.zeros(2)
        self.moving = False
        self._frame = 0
        self._warned = False

    @property
    def offset(self) -> np.ndarray:
        """(x, y) pixels the scene has moved in the image since the first frame."""
        return self._offset

    def update(self, image: np.ndarray | None) -> np.ndarray:
        """Feed the next frame ((H, W) grey or (H, W, 3) RGB uint8; None: no image, no shift); return the
        shift (x, y pixels) of the scene since the previous frame."""
        self._frame += 1
        if self._scene is None or image is None:
            return np.zeros(2)
        grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
        offset = np.array(self._scene.update(grey))
        if self._scene.failed and not self._warned:
            log.warning(
                "camera motion: frame %d has no texture to measure the scene's shift on (no confident "
                "tile); the tracker applies no shift there (said once per sequence)",
                self._frame,
            )
            self._warned = True
        shift, self._offset = offset - self._offset, offset
        self.moving = self.moving or bool(np.any(shift))
        return shift
