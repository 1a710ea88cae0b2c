"""DeepSORT for one sequence: the detection-level filters in front of the tracker, and its output rule.

Constructor keys are the reference's vocabulary and the config keys of `conf/tracker/*.yaml`, so the
paper's Table 2 maps onto them one to one.
"""

from __future__ import annotations

import numpy as np

from spacetrack.tracking.detection import Detections
from spacetrack.tracking.io import iter_frames
from spacetrack.tracking.kalman_filter import CHI2_95_4DOF
from spacetrack.tracking.nn_matching import NearestNeighborDistanceMetric
from spacetrack.tracking.preprocessing import filter_detections
from spacetrack.tracking.tracker import Tracker


class DeepSort:
    """Frame-by-frame tracker: confidence floor, NMS, then predict + update.

    max_cosine_distance: appearance gate t(2) (eq. 14); None associates by IoU alone (SORT).
    nn_budget: features kept per track (eq. 13's R_n); None keeps all.
    max_iou_distance, max_age, n_init, lambda_, gating_threshold: see `Tracker`.
    min_confidence: detections below this confidence are dropped before tracking.
    nms_max_overlap: NMS overlap limit (intersection over the other box's area); 1 disables it.
    min_detection_height: detections lower than this (pixels) are dropped.
    """

    def __init__(
        self,
        *,
        max_cosine_distance: float | None,
        nn_budget: int | None,
        max_iou_distance: float,
        max_age: int,
        n_init: int,
        min_confidence: float,
        nms_max_overlap: float,
        lambda_: float = 0.0,
        gating_threshold: float = CHI2_95_4DOF,
        min_detection_height: float = 0.0,
    ) -> None:
        metric = None
        if max_cosine_distance is not None:
            metric = NearestNeighborDistanceMetric(
                max_cosine_distance=max_cosine_distance, nn_budget=nn_budget
            )
        self.tracker = Tracker(
            metric=metric,
            max_iou_distance=max_iou_distance,
            max_age=max_age,
            n_init=n_init,
            lambda_=lambda_,
            gating_threshold=gating_threshold,
        )
        self.min_confidence = min_confidence
        self.nms_max_overlap = nms_max_overlap
        self.min_detection_height = min_detection_height

    def step(self, tlwh: np.ndarray, confidence: np.ndarray, feature: np.ndarray | None = None) -> np.ndarray:
        """Track one frame of detections (boxes `tlwh` (N, 4) pixels, confidences (N,), features (N, D)).

        Returns the frame's output tracks as rows (track id, x, y, w, h), box `tlwh` of the track state.
        """
        keep = filter_detections(
            tlwh,
            confidence,
            min_confidence=self.min_confidence,
            nms_max_overlap=self.nms_max_overlap,
            min_detection_height=self.min_detection_height,
        )
        tlwh = np.asarray(tlwh, dtype=float).reshape(-1, 4)[keep]
        confidence = np.asarray(confidence, dtype=float).reshape(-1)[keep]
        if feature is not None:
            feature = np.asarray(feature, dtype=float)[keep]
        self.tracker.predict()
        self.tracker.update(Detections.create(tlwh, confidence, feature))
        out = self.tracker.outputs()
        if not out:
            return np.zeros((0, 5))
        return np.array([[track_id, *box] for track_id, box in out])


def track_sequence(tracker: DeepSort, dets: np.ndarray) -> np.ndarray:
    """Run `tracker` over a validated detection array (`tracking.io.load_detections` layout).

    Every frame from the first to the last in `dets` is stepped, empty ones included, so tracks age
    through gaps. Returns rows (frame, id, x, y, w, h), box `tlwh` in pixels.
    """
    results = []
    for frame, rows in iter_frames(dets):
        out = tracker.step(rows[:, 2:6], rows[:, 6], rows[:, 10:])
        results.append(np.column_stack([np.full(len(out), frame), out]))
    return np.concatenate(results) if results else np.zeros((0, 6))
