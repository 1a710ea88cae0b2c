"""The streaming front of the pipeline: enhancement -> detector -> re-ID -> motion fusion -> dynamic filter.

Frames are processed as they come. The detector and the re-ID encoder answer for frame t at once; the
motion fusion answers for frame t only `motion.latency` frames later (2 for the paper's five-frame
difference), so each frame's detections wait in a short queue until its moving blobs are known. Frames
before the first motion mask take the blobs of that mask; the last frames, which never get one, take
the blobs of the last mask.

The motion stage needs only the raw frame, so by default it runs in a worker thread while the detector and
the re-ID encoder work on the same frame (OpenCV, torch and ONNX Runtime release the GIL): on two cores the
motion fusion then costs little wall time. And the re-ID encoder, which needs the frame's boxes, by default
encodes frame t in another worker thread while the detector already works on frame t + 1: the two networks
then share the cores instead of taking turns. The answers are identical either way.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Generator, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import ExitStack
from dataclasses import dataclass

import numpy as np

from spacetrack.data.layout import BOX, CONF, FRAME
from spacetrack.motion import DynamicFilter, MotionDetector
from spacetrack.motion.blobs import Blob
from spacetrack.pipeline.sources import FrameSource
from spacetrack.pipeline.timing import StageTimer
from spacetrack.tracking.io import HEAD_COLUMNS


@dataclass
class FrameDetections:
    """One frame's detections: `rows` in the reference DeepSORT layout (N, 10 + D: `frame,-1,x,y,w,h,confidence,-1,-1,-1`, features), `dynamic` (N,) bool, `classes`
    (N,) class indices, the RGB `image` when the stream keeps images (for drawing), and the moving `blobs`
    the dynamic flags came from (None without a motion stage)."""

    frame: int
    rows: np.ndarray
    dynamic: np.ndarray
    classes: np.ndarray
    image: np.ndarray | None
    blobs: list[Blob] | None = None


def dynamic_flags(dynamic_filter: DynamicFilter, rows: np.ndarray, blobs: list[Blob] | None) -> np.ndarray:
    """(N,) bool: which detection rows (the DeepSORT layout) move by `blobs`; all of them with no motion stage."""
    return np.ones(len(rows), bool) if blobs is None else dynamic_filter(rows[:, BOX], blobs)


def detection_rows(frame: int, boxes: np.ndarray, features: np.ndarray) -> np.ndarray:
    """(N, 10 + D) rows `frame,-1,x,y,w,h,score,-1,-1,-1,feature` from (N, >=5) `x,y,w,h,score` boxes and
    (N, D) features (N may be 0)."""
    n = len(boxes)
    head = np.full((n, HEAD_COLUMNS), -1.0)
    head[:, FRAME] = frame
    head[:, BOX] = boxes[:, :4]
    head[:, CONF] = boxes[:, 4]
    return np.hstack([head, np.asarray(features, dtype=np.float64)])


class DetectionStream:
    """Runs the per-frame stages over a source and yields `FrameDetections` in frame order.

    enhancer: RGB -> RGB for the detector's input (`conf/enhance/`); motion and re-ID see the raw frame,
        as they were tuned and trained on it.
    detector: `(rgb, frame) -> (N, 6)` rows `x,y,w,h,score,class` (see `pipeline.detector`).
    encoder: `(rgb, boxes_tlwh) -> (N, D)` re-ID features, or None for no appearance (D = 0).
    motion: a streaming motion detector with `blobs` (the paper's `Fusion`), or None to call every
        detection dynamic.
    dynamic_filter: marks boxes dynamic from the blobs (`motion.DynamicFilter`).
    overlap_motion: run the motion stage in a worker thread beside the detector and re-ID of the same
        frame; the `motion` timing is then only the time spent waiting for it.
    overlap_reid: encode each frame's boxes in a worker thread while the detector works on the next
        frame; the `reid` timing is then only the time spent waiting for it.
    reid_min_score: only detections scoring at least this are encoded; the others get an all-zero
        feature (cosine distance 1 to everything). A tracker drops them before associating anyway when
        its `min_confidence` is at least this, so their features would never be read.
    """

    def __init__(
        self,
        *,
        enhancer: Callable[[np.ndarray], np.ndarray],
        detector: Callable[[np.ndarray, int], np.ndarray],
        encoder: Callable[[np.ndarray, np.ndarray], np.ndarray] | None,
        motion: MotionDetector | None,
        dynamic_filter: DynamicFilter,
        timer: StageTimer | None = None,
        overlap_motion: bool = True,
        overlap_reid: bool = True,
        reid_min_score: float = 0.0,
    ) -> None:
        self.enhancer, self.detector, self.encoder = enhancer, detector, encoder
        self.motion, self.dynamic_filter = motion, dynamic_filter
        self.overlap_motion = overlap_motion
        self.overlap_reid = overlap_reid
        self.reid_min_score = reid_min_score
        self.timer = timer or StageTimer()

    @property
    def latency(self) -> int:
        """Frames the stream reads past a frame before it yields that frame's detections: the motion
        stage's latency, plus one with `overlap_reid` (the re-ID of a frame ends during the next one's)."""
        reid_lag = int(self.encoder is not None and self.overlap_reid)
        return (self.motion.latency if self.motion is not None else 0) + reid_lag

    def run(self, source: FrameSource, *, keep_images: bool = False) -> Iterator[FrameDetections]:
        timer = self.timer
        self.detector.begin(source)
        if self.motion is not None:
            self.motion.reset()
        pending: deque[tuple[int, np.ndarray | None, np.ndarray, np.ndarray]] = deque()
        blobs: list[Blob] | None = None
        with ExitStack() as stack:
            motion_worker = reid_worker = None
            if self.motion is not None and self.overlap_motion:
                motion_worker = stack.enter_context(ThreadPoolExecutor(1, thread_name_prefix="motion"))
            if self.encoder is not None and self.overlap_reid:
                reid_worker = stack.enter_context(ThreadPoolExecutor(1, thread_name_prefix="reid"))
            # the frame whose detector boxes are in and whose re-ID features and motion mask may still be
            # on their way: (frame, rgb, boxes, features or their Future, motion mask Future or None)
            previous = None
            for frame, rgb in enumerate(source, start=1):
                motion = motion_worker.submit(self._motion_step, rgb) if motion_worker is not None else None
                with timer("enhance"):
                    enhanced = self.enhancer(rgb)
                with timer("detector"):
                    boxes = self.detector(enhanced, frame)
                if previous is not None:  # its re-ID ran beside this frame's detector
                    blobs = yield from self._finish(*previous, pending, blobs, keep_images)
                if reid_worker is not None:
                    features = reid_worker.submit(self._features, rgb, boxes)
                else:
                    with timer("reid"):
                        features = self._features(rgb, boxes)
                previous = (frame, rgb, boxes, features, motion)
            if previous is not None:
                blobs = yield from self._finish(*previous, pending, blobs, keep_images)
        while pending:
            yield self._resolve(pending.popleft(), blobs or [])

    def _finish(
        self,
        frame: int,
        rgb: np.ndarray,
        boxes: np.ndarray,
        features: np.ndarray | Future,
        motion: Future | None,
        pending: deque,
        blobs: list[Blob] | None,
        keep_images: bool,
    ) -> Generator[FrameDetections, None, list[Blob] | None]:
        """Queue one frame's detections once its features are in; yield every queued frame whose motion
        mask is known (frames in order). Returns the blobs of the latest motion mask (`blobs` if none
        came)."""
        if isinstance(features, Future):
            with self.timer("reid"):
                features = features.result()
        pending.append(
            (frame, rgb if keep_images else None, detection_rows(frame, boxes, features), boxes[:, 5])
        )
        if self.motion is None:
            yield self._resolve(pending.popleft(), None)
            return blobs
        with self.timer("motion"):
            mask, index, new_blobs = motion.result() if motion is not None else self._motion_step(rgb)
        if mask is None:
            return blobs
        blobs = new_blobs
        while pending and pending[0][0] <= index + 1:  # index: 0-based frame the mask belongs to
            yield self._resolve(pending.popleft(), blobs)
        return blobs

    def _motion_step(self, rgb: np.ndarray) -> tuple[np.ndarray | None, int, list[Blob]]:
        """Feed a frame to the motion stage: its mask (or None), the 0-based frame the mask belongs to, and
        its blobs, read together (the worker may move on to the next frame before they are used)."""
        mask = self.motion.apply(rgb)
        return mask, self.motion.mask_index, list(self.motion.blobs) if mask is not None else []

    def _features(self, rgb: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        """(N, D) re-ID features of the (N, 6) boxes; zeros below `reid_min_score`; D = 0 with no encoder."""
        if self.encoder is None:
            return np.zeros((len(boxes), 0))
        wanted = boxes[:, 4] >= self.reid_min_score
        if wanted.all():
            return self.encoder(rgb, boxes[:, :4])
        features = np.zeros((len(boxes), self.encoder.feature_dim), np.float32)
        if wanted.any():
            features[wanted] = self.encoder(rgb, boxes[wanted, :4])
        return features

    def _resolve(self, item: tuple, blobs: list[Blob] | None) -> FrameDetections:
        frame, image, rows, classes = item
        with self.timer("dynamic"):
            dynamic = dynamic_flags(self.dynamic_filter, rows, blobs)
        return FrameDetections(frame, rows, dynamic, classes.astype(int), image, blobs)
