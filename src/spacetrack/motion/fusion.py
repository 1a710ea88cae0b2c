"""The paper's dynamic-target fusion detection (Fig. 8): a frame difference 'and' a background model.

Both masks are smoothed (Gaussian filter, re-binarised) and closed (morphology), combined with a logical
'and', split into regions (tiny ones dropped), their holes filled, and the result smoothed by a
last Gaussian filter. The difference cannot keep a target that stopped, and the background model supplies
the full body that the difference leaves hollow; the 'and' keeps only what both agree on, so light changes
(which the difference's adaptive threshold ignores) and ghosts (which the difference does not have) both
drop out. The 'and' is the paper's pixel-wise one (`combine="pixel"`) or, by default, region-wise: a
background region is kept whole when the difference confirms it (`confirmed_regions`).
"""

from __future__ import annotations

from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor

import cv2
import numpy as np

from spacetrack.motion.blobs import Blob, find_blobs, outlines
from spacetrack.motion.frames import FrameGuard, MotionDetector, to_grey


def _smooth(mask: np.ndarray, ksize: int, level: int) -> np.ndarray:
    """Gaussian-filter a 0/255 mask and re-binarise it: pixels above `level` (0-255) become 255."""
    if ksize <= 1:
        return mask
    _, out = cv2.threshold(cv2.GaussianBlur(mask, (ksize, ksize), 0), level, 255, cv2.THRESH_BINARY)
    return out


def fill_regions(mask: np.ndarray, *, min_area: float = 0.0) -> np.ndarray:
    """`mask` (0/255) with every hole filled and the regions enclosing < `min_area` px² dropped.

    Drawing the outer outlines filled does both in one pass.
    """
    kept = outlines(mask, min_area=min_area)
    return cv2.drawContours(np.zeros_like(mask), kept, -1, 255, thickness=cv2.FILLED)


def filled_hull(mask: np.ndarray, margin: int = 0) -> np.ndarray:
    """0/255 mask of the convex hull of the non-zero pixels of `mask`, grown by `margin` pixels (a dilation
    by a disk). Only each row's first and last pixel can be a vertex, so the hull is taken of those."""
    on = mask > 0
    rows = np.flatnonzero(on.any(axis=1))
    first = on[rows].argmax(axis=1)
    last = on.shape[1] - 1 - on[rows, ::-1].argmax(axis=1)
    ends = np.concatenate([np.stack([first, rows], axis=1), np.stack([last, rows], axis=1)])
    filled = cv2.fillConvexPoly(np.zeros_like(mask), cv2.convexHull(ends.astype(np.int32)), 255)
    if margin > 0:
        size = 2 * margin + 1
        filled = cv2.dilate(filled, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size)))
    return filled


def confirmed_regions(
    body: np.ndarray,
    evidence: np.ndarray,
    *,
    min_area: float = 0.0,
    min_support: int = 1,
    hull_margin: int | None = None,
    hull_min_fill: float = 0.0,
) -> np.ndarray:
    """The regions of `body` (0/255, holes filled) holding >= `min_support` pixels of `evidence`: an 'and'
    of regions instead of pixels. Regions enclosing < `min_area` px² are dropped.

    With `hull_margin` (pixels), a kept region is cut down to the convex hull of its evidence pixels grown
    by that margin: the part of a region that the evidence does not reach (a background model's ghost
    where a target stood when the model started, joined to the target that has just left it) goes. Only
    regions whose evidence pixels fill at least `hull_min_fill` (0-1) of them are cut: sparse evidence (a
    dim target's few changing pixels) spans too small a hull.
    """
    out = np.zeros_like(body)
    for contour in outlines(body, min_area=min_area):
        x, y, w, h = cv2.boundingRect(contour)
        region = cv2.drawContours(np.zeros((h, w), np.uint8), [contour], -1, 255, cv2.FILLED, offset=(-x, -y))
        support = cv2.bitwise_and(region, evidence[y : y + h, x : x + w])
        found = cv2.countNonZero(support)
        if found < min_support:
            continue
        if hull_margin is not None and found >= hull_min_fill * cv2.countNonZero(region):
            region = cv2.bitwise_and(region, filled_hull(support, hull_margin))
        view = out[y : y + h, x : x + w]
        cv2.bitwise_or(view, region, dst=view)
    return out


class Fusion:
    """Streaming fusion of two detectors; latency = the larger of the two, masks are paired by frame.

    Args:
        difference: a frame-difference detector (the paper: `FiveFrameDifference`).
        background: a background-model detector (the paper: `ViBe`).
        blur_ksize: Gaussian kernel (odd pixels) applied to each input mask; 1 = none.
        blur_level: re-binarisation level after that filter, 0-255 (below 128 grows a mask, above shrinks).
        close_ksize: elliptical closing kernel (pixels) applied to each input mask; 1 = none.
        min_area: regions enclosing less than this (square pixels) after the 'and' are dropped.
        final_ksize: Gaussian kernel of the last smoothing (odd pixels); 1 = none.
        combine: "pixel": the paper's pixel-wise 'and'; "region": keep the background model's whole
            regions (holes filled) that hold at least `min_support` moving pixels of the difference. A
            slow target's difference mask is an outline with a hollow middle; the pixel 'and' keeps only
            the outline, the region 'and' the body around it.
        min_support: difference pixels a region needs in "region" mode.
        hull_margin: "region" mode: cut each kept region down to the convex hull of the difference's pixels
            in it, grown by this many pixels; None keeps regions whole.
        hull_min_fill: cut only regions whose difference pixels fill at least this share (0-1) of them.
        parallel: run the background model in a worker thread, a frame ahead of the calling thread, which
            runs the difference and all the filtering, so the two use two cores; the masks are the same
            either way. `apply` then returns while the worker still takes the frame just fed: `flush`
            waits for it, `close` also stops the worker.

    When both detectors compensate camera motion the same way they share one scene-shift estimator (each
    frame's shift is measured once).
    """

    def __init__(
        self,
        *,
        difference: MotionDetector,
        background: MotionDetector,
        blur_ksize: int = 5,
        blur_level: int = 127,
        close_ksize: int = 5,
        min_area: float = 4.0,
        final_ksize: int = 5,
        combine: str = "region",
        min_support: int = 3,
        hull_margin: int | None = 10,
        hull_min_fill: float = 0.3,
        parallel: bool = False,
    ) -> None:
        if combine not in ("pixel", "region"):
            raise ValueError(f"combine must be 'pixel' or 'region', got {combine!r}")
        for name, k in (("blur_ksize", blur_ksize), ("final_ksize", final_ksize)):
            if k < 1 or k % 2 == 0:
                raise ValueError(f"{name} must be an odd number of pixels >= 1, got {k}")
        self.difference = difference
        self.background = background
        self.blur_ksize = blur_ksize
        self.blur_level = blur_level
        self.close_ksize = close_ksize
        self.min_area = min_area
        self.final_ksize = final_ksize
        self.combine = combine
        self.min_support = min_support
        if hull_margin is not None and hull_margin < 0:
            raise ValueError(f"hull_margin must be >= 0 pixels or None, got {hull_margin}")
        self.hull_margin = hull_margin
        if not 0.0 <= hull_min_fill <= 1.0:
            raise ValueError(f"hull_min_fill must be a share in [0, 1], got {hull_min_fill}")
        self.hull_min_fill = hull_min_fill
        self.parallel = parallel
        modes = getattr(difference, "compensate", False), getattr(background, "compensate", False)
        if modes[0] and modes[0] == modes[1]:
            background.scene_shift = difference.scene_shift  # both see the same frames: measure once
        self._worker: ThreadPoolExecutor | None = None
        self._in_flight: Future | None = None  # `parallel`: the background model's work on the last frame
        self._guard = FrameGuard()
        self.latency = max(difference.latency, background.latency)
        self._kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (close_ksize, close_ksize))
        self.reset()

    def reset(self) -> None:
        if self._in_flight is not None:
            self._in_flight.exception()  # let the worker finish; what it was doing is forgotten
            self._in_flight = None
        self._guard.reset()
        self.difference.reset()
        self.background.reset()
        # (frame index, mask) of each detector, waiting until the other one has the same frame.
        self._pending: tuple[deque, deque] = (deque(), deque())
        self._mask_index = -1
        self.blobs: list[Blob] = []

    @property
    def mask_index(self) -> int:
        """0-based index of the frame the latest mask (and `blobs`) refer to."""
        return self._mask_index

    def apply(self, frame: np.ndarray) -> np.ndarray | None:
        """Fused (H, W) uint8 mask (255 = moving) of frame `mask_index`, or None; also sets `blobs`."""
        given = frame = self._guard.check(frame)
        if not getattr(self.background, "colour", False):
            frame = to_grey(frame)  # neither part looks at colour: convert once for both
        if self.parallel:
            self.flush()  # the background model's previous frame: at most one frame in flight
            if self._worker is None:
                self._worker = ThreadPoolExecutor(1, thread_name_prefix="fusion")
            if np.may_share_memory(frame, given):
                frame = frame.copy()  # the worker may still read it after this call returns
            self._in_flight = self._worker.submit(self._background_mask, frame)
            self._step(self.difference, frame, 0)
            first, second = self._pending
            if first and (not second or second[-1][0] < first[0][0]):
                self.flush()  # the difference is ahead (a longer latency than the background's)
        else:
            self._step(self.difference, frame, 0)
            self._step(self.background, frame, 1)
        first, second = self._pending
        # A detector may start later than its latency says (it needs frames on both sides): skip the
        # frames only one of them has a mask for.
        while first and second and first[0][0] != second[0][0]:
            (first if first[0][0] < second[0][0] else second).popleft()
        if not (first and second):
            return None
        (self._mask_index, a), (_, b) = first.popleft(), second.popleft()
        if self.combine == "pixel":
            fused = fill_regions(cv2.bitwise_and(a, b), min_area=self.min_area)
        else:
            fused = confirmed_regions(
                b,
                a,
                min_area=self.min_area,
                min_support=self.min_support,
                hull_margin=self.hull_margin,
                hull_min_fill=self.hull_min_fill,
            )
        fused = _smooth(fused, self.final_ksize, 127)
        self.blobs = find_blobs(fused, min_area=self.min_area)
        return fused

    def flush(self) -> None:
        """Wait until the background model has taken every frame fed so far (`parallel` leaves it working
        on the last frame when `apply` returns); raises what it raised."""
        if self._in_flight is not None:
            in_flight, self._in_flight = self._in_flight, None
            mask_index, mask = in_flight.result()
            if mask is not None:
                self._pending[1].append((mask_index, self._prepare(mask)))

    def close(self) -> None:
        """Wait for the background model, then stop the worker thread of `parallel` (a later `apply`
        starts a new one)."""
        try:
            self.flush()
        finally:
            if self._worker is not None:
                self._worker.shutdown()
                self._worker = None

    def _background_mask(self, frame: np.ndarray) -> tuple[int, np.ndarray | None]:
        """Runs on the worker: the background model's raw mask of `frame` and its frame index."""
        mask = self.background.apply(frame)
        return self.background.mask_index, mask

    def _step(self, detector: MotionDetector, frame: np.ndarray, side: int) -> None:
        """Feed `frame` to one detector and queue its filtered mask (if any) on `side` (0: difference)."""
        mask = detector.apply(frame)
        if mask is not None:
            self._pending[side].append((detector.mask_index, self._prepare(mask)))

    def _prepare(self, mask: np.ndarray) -> np.ndarray:
        mask = _smooth(mask, self.blur_ksize, self.blur_level)
        if self.close_ksize > 1:
            mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, self._kernel)
        return mask
