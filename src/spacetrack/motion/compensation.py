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
        probe_every: 0 measures every frame. N > 0 (`compensate: auto` in the detectors) first only probes
            every N-th frame against the previous probe, and measures every frame from the first probe
            that finds the scene moved (at least N * min_step pixels, by the median of at least three
            confident tiles) on: a still camera pays one measurement in N frames and its offset stays
            exactly zero; a slewing one is compensated from its first probe on (not the frames before).
        first_probe: with `probe_every`, also probe the second frame against the first (a one-frame shift of
            at least `min_step`), so that a camera slewing from the start is compensated from its second
            frame instead of its (probe_every + 1)-th; when that probe finds nothing, the schedule goes on
            as without it.

    Detectors fed the same frames can share one estimator (the fusion's two parts do): `update` with the
    caller's frame number measures each frame once and hands its offset to the next caller too.
    """

    def __init__(
        self,
        *,
        tile: int = 128,
        min_response: float = 0.05,
        min_step: float = 0.25,
        probe_every: int = 0,
        first_probe: bool = False,
    ) -> None:
        if tile < 8:
            raise ValueError(f"tile must be >= 8 pixels, got {tile}")
        if min_step < 0:
            raise ValueError(f"min_step must be >= 0 pixels, got {min_step}")
        if probe_every < 0:
            raise ValueError(f"probe_every must be >= 0 frames, got {probe_every}")
        self.probe_every = probe_every
        self.first_probe = first_probe
        self.tile = tile
        self.min_response = min_response
        self.min_step = min_step
        self._lock = threading.Lock()  # sharers may call from two threads (the fusion's `parallel`)
        self.reset()

    def reset(self) -> None:
        with self._lock:
            self._previous: np.ndarray | None = None
            self._previous_frame = 0  # the count (1-based) of the frame `_previous` holds
            self._window: np.ndarray | None = None
            self._position = np.zeros(2)
            self._frames = 0
            self.moving = self.probe_every == 0  # False while `probe_every` still waits for motion

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
        if not self.moving:
            self._probe(grey)
        else:
            current = grey.astype(np.float32)
            if self._previous is not None:
                step, _ = self._step(self._previous, current)
                if np.hypot(*step) >= self.min_step:
                    self._position += step
            self._previous = current
        return float(self._position[0]), float(self._position[1])

    def _probe(self, grey: np.ndarray) -> None:
        """Every `probe_every` frames (and with `first_probe` on the second frame): has the scene moved
        since the last probe? Trusted only from several agreeing tiles (one tile may hold nothing but a
        large target)."""
        early = self.first_probe and self._frames == 2
        if not early and (self._frames - 1) % self.probe_every:
            return
        current = grey.astype(np.float32)
        found = False
        if self._previous is not None:
            step, tiles = self._step(self._previous, current)
            elapsed = self._frames - self._previous_frame
            found = tiles >= PROBE_MIN_TILES and np.hypot(*step) >= self.min_step * elapsed
            if found:
                self._position += step
                self.moving = True
        if found or not early:  # an early probe that found nothing leaves the schedule as it was
            self._previous, self._previous_frame = current, self._frames

    def _step(self, previous: np.ndarray, current: np.ndarray) -> tuple[np.ndarray, int]:
        """Median shift (x, y) of the confident tiles from `previous` to `current` (zero without any),
        and how many tiles were confident."""
        h, w = current.shape
        side = min(self.tile, h, w)
        if self._window is None:
            self._window = cv2.createHanningWindow((side, side), cv2.CV_32F)
        shifts = []
        for top in range(0, h - side + 1, side):
            for left in range(0, w - side + 1, side):
                window = (slice(top, top + side), slice(left, left + side))
                (dx, dy), response = cv2.phaseCorrelate(previous[window], current[window], self._window)
                if np.isfinite(response) and response >= self.min_response:
                    shifts.append((dx, dy))
        return (np.median(np.array(shifts), axis=0) if shifts else np.zeros(2)), len(shifts)


PROBE_EVERY = 10  # frames between the probes of `compensate: auto`
PROBE_MIN_TILES = 3  # confident tiles a probe needs to find the scene moving


def scene_shift_for(compensate: bool | str) -> SceneShift:
    """The estimator a detector's `compensate` setting asks for: False or True (measure every frame) or
    "auto" (probe every PROBE_EVERY frames until the scene moves); anything else is an error."""
    if compensate not in (False, True, "auto"):
        raise ValueError(f"compensate must be false, true or auto, got {compensate!r}")
    return SceneShift(probe_every=PROBE_EVERY if compensate == "auto" else 0)
