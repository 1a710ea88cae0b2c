"""DeepSORT for one sequence: the detection-level filters in front of the tracker, and its output rule.

Constructor keys are the reference's vocabulary and the config keys of `conf/tracker/*.yaml`, so the
paper's Table 2 maps onto them one to one.
"""

from __future__ import annotations

import numpy as np

from spacetrack.data.layout import BOX, CONF
from spacetrack.tracking.camera_motion import CameraMotion
from spacetrack.tracking.class_vote import ClassVotes
from spacetrack.tracking.detection import Detections
from spacetrack.tracking.dynamic import TrackDynamics
from spacetrack.tracking.io import FEATURES, iter_frames
from spacetrack.tracking.iou_matching import intersections, iou_matrix
from spacetrack.tracking.kalman_filter import CHI2_95_4DOF
from spacetrack.tracking.nn_matching import NearestNeighborDistanceMetric
from spacetrack.tracking.preprocessing import filter_detections
from spacetrack.tracking.tracker import Tracker

# A low-scored detection overlapping a kept one at this IoU or more is that object named again (the
# detector suppresses overlaps within a class only), not a second target.
LOW_DUPLICATE_IOU = 0.5


class DeepSort:
    """Frame-by-frame tracker: confidence floor, NMS, then predict + update.

    max_cosine_distance: appearance gate t(2) (eq. 14); None associates by IoU alone (SORT).
    nn_budget: features kept per track (eq. 13's R_n); None keeps all.
    max_iou_distance, max_age, n_init, lambda_, gating_threshold: see `Tracker`.
    min_confidence: detections below this confidence are dropped before tracking.
    nms_max_overlap: NMS overlap limit (intersection over the other box's area); 1 disables it.
    min_detection_height: detections lower than this (pixels) are dropped.
    camera_motion: beyond the reference, move each prediction by the scene's shift measured on the frame
        passed to `step` (`tracking.camera_motion`): false (never), true, or auto (once the camera is
        found moving; a still camera gives exactly the tracks of false).
    dynamics: beyond the reference, decide per track what moves (`tracking.dynamic`) from the per-box
        blob flags passed to `step` and the track's own motion against the scene, and output only the
        tracks that move; None outputs every confirmed track.
    output_box: state (the reference: the Kalman state's box) or detection (the matched detection's box
        on frames with one).
    reacquire_gate: beyond the reference, a last matching stage for confirmed tracks by the predicted
        box centre alone (see `Tracker`); None: none.
    coast_in_view: beyond the reference, a confirmed track left unmatched on a frame is output on its
        prediction only while that box lies inside the image (see `Tracker`); false: always, as the
        reference does.
    occluded_area: beyond the reference, a matched box under this share of its track's whole area
        (an occluder cuts it) leaves the track's state as predicted (see `Tracker`); None: the reference.
    low_confidence: beyond the reference, detections scoring from this up to `min_confidence` are kept
        aside (not when a kept detection overlaps them at IoU `LOW_DUPLICATE_IOU` or more: the same object
        named twice) and serve only to keep confirmed tracks that every other stage left unmatched, by box
        overlap (ByteTrack's second association, see `Tracker`); they never start a track. At or above
        `min_confidence` no detection is in that range (so a sweep of `min_confidence` may cross it).
        None: dropped, as the reference does.
    motion_rescue: beyond the reference, the moving blobs passed to `step` that touch no detection of the
        frame (kept or low-scored) are offered, like the low-scored detections and with them, to the
        confirmed tracks every other stage left unmatched, by box overlap: a small or faint target the
        detector misses for a few frames while the motion stage still sees it keeps its track on the
        blob's box. A blob adds no appearance feature and no class vote, and starts no track.
        False: blobs only flag detections dynamic.
    motion_confirm: beyond the reference, a detection scoring from this up to `min_confidence` whose box a
        moving blob matched (its `dynamic` flag passed to `step`) counts as a kept one: it matches, feeds
        appearance and may start a track, as a detection at `min_confidence` does. A faint target the
        detector scores low but the motion stage sees move is tracked; a low score on what does not move
        (a star, a parked object, a part lit alone beside its moving whole when no blob matches it) stays
        below. One the matching stages leave unmatched is first offered to confirmed tracks with the
        low-scored boxes, as it would have been without the floor. Needs the per-box flags of the
        track-level motion decision (`dynamics`). None: the reference's single floor.
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
        camera_motion: bool | str = False,
        dynamics: TrackDynamics | None = None,
        output_box: str = "state",
        reacquire_gate: float | None = None,
        coast_in_view: bool = False,
        occluded_area: float | None = None,
        low_confidence: float | None = None,
        motion_rescue: bool = False,
        motion_confirm: float | None = None,
    ) -> None:
        if low_confidence is not None and not low_confidence >= 0.0:
            raise ValueError(f"tracker.low_confidence must be >= 0 or null, got {low_confidence}")
        if motion_confirm is not None:
            if isinstance(motion_confirm, bool) or not motion_confirm >= 0.0:
                raise ValueError(f"tracker.motion_confirm must be >= 0 or null, got {motion_confirm!r}")
            if dynamics is None:
                raise ValueError(
                    f"tracker.motion_confirm={motion_confirm} needs each box's motion flag, which only "
                    "dynamic_filter=track passes to the tracker (null turns it off)"
                )
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
            dynamics=dynamics,
            output_box=output_box,
            reacquire_gate=reacquire_gate,
            coast_in_view=coast_in_view,
            occluded_area=occluded_area,
        )
        self.camera = CameraMotion(camera_motion)
        self.min_confidence = min_confidence
        self.low_confidence = low_confidence
        self.motion_rescue = bool(motion_rescue)
        self.motion_confirm = None if motion_confirm is None else float(motion_confirm)
        self.nms_max_overlap = nms_max_overlap
        self.min_detection_height = min_detection_height

    @property
    def needs_images(self) -> bool:
        """Whether `step` uses the frame (to measure the camera's motion)."""
        return self.camera.mode is not False

    def step(
        self,
        tlwh: np.ndarray,
        confidence: np.ndarray,
        feature: np.ndarray | None = None,
        *,
        dynamic: np.ndarray | None = None,
        image: np.ndarray | None = None,
        classes: np.ndarray | None = None,
        blobs: np.ndarray | None = None,
    ) -> np.ndarray:
        """Track one frame of detections (boxes `tlwh` (N, 4) pixels, confidences (N,), features (N, D)).

        dynamic: (N,) bool, whether a motion blob matched each box (the evidence of `dynamics` and of
            `motion_confirm`; None: all, and `motion_confirm` confirms nothing).
        image: the frame (RGB or grey uint8), for `camera_motion`; None applies no shift.
        classes: (N,) the detector's class index of each box, for each track's class vote (`class_votes`);
            None: unknown.
        blobs: (B, 4) `tlwh` boxes of the frame's moving blobs, for `motion_rescue` (None: no blobs).
        Returns the frame's output tracks as rows (track id, x, y, w, h), box `tlwh` of the track state.
        """
        tlwh = np.asarray(tlwh, dtype=float).reshape(-1, 4)
        confidence = np.asarray(confidence, dtype=float).reshape(-1)
        if feature is not None:
            feature = np.asarray(feature, dtype=float)
        if dynamic is not None:
            dynamic = np.asarray(dynamic, dtype=bool).reshape(-1)
        if classes is not None:
            classes = np.asarray(classes).astype(int).reshape(-1)

        def chosen(keep: np.ndarray) -> Detections:
            return Detections.create(
                tlwh[keep],
                confidence[keep],
                None if feature is None else feature[keep],
                None if dynamic is None else dynamic[keep],
                None if classes is None else classes[keep],
            )

        eligible = confidence >= self.min_confidence
        floor = self.min_confidence
        if self.motion_confirm is not None and dynamic is not None:
            eligible |= dynamic & (confidence >= self.motion_confirm)
            floor = min(floor, self.motion_confirm)
        # NMS among the eligible ones by their own scores
        keep = self._kept(tlwh, np.where(eligible, confidence, -np.inf), floor)
        low = None
        if self.low_confidence is not None:
            under = np.where(eligible, -np.inf, confidence)  # the kept ones left out
            below = self._kept(tlwh, under, self.low_confidence)
            duplicate = iou_matrix(tlwh[below], tlwh[keep]).max(axis=1, initial=0.0) >= LOW_DUPLICATE_IOU
            low = chosen(below[~duplicate])
        if self.motion_rescue and blobs is not None:
            low = self._with_blobs(low, np.asarray(blobs, dtype=float).reshape(-1, 4), tlwh[keep], feature)
        shift = self.camera.update(image)
        self.tracker.predict((float(shift[0]), float(shift[1])))
        offset = self.camera.offset
        self.tracker.update(
            chosen(keep),
            (float(offset[0]), float(offset[1])),
            camera_moving=self.camera.moving,
            frame_size=None if image is None else (image.shape[1], image.shape[0]),
            low=low,
            weak=None if self.motion_confirm is None else confidence[keep] < self.min_confidence,
        )
        return track_rows(self.tracker.outputs())

    @staticmethod
    def _with_blobs(
        low: Detections | None, blobs: np.ndarray, kept: np.ndarray, feature: np.ndarray | None
    ) -> Detections | None:
        """`low` and the `blobs` that touch no kept or low detection, as detections of score 0 that move,
        with no class and zero features."""
        boxes = kept if low is None else np.concatenate([kept, low.tlwh])
        free = blobs[~(intersections(blobs, boxes)[0] > 0).any(axis=1)]
        if not len(free):
            return low
        dim = 0 if feature is None else feature.shape[1]
        moving = Detections.create(free, np.zeros(len(free)), np.zeros((len(free), dim)))
        return moving if low is None else low.concat(moving)

    def _kept(self, tlwh: np.ndarray, confidence: np.ndarray, floor: float) -> np.ndarray:
        """Indices of the detections scoring `floor` or more that pass the height floor and NMS."""
        return filter_detections(
            tlwh,
            confidence,
            min_confidence=floor,
            nms_max_overlap=self.nms_max_overlap,
            min_detection_height=self.min_detection_height,
        )

    @property
    def class_votes(self) -> ClassVotes:
        """Each track's class, voted over its matched detections (every track of the sequence so far)."""
        return self.tracker.votes

    def output_classes(self) -> np.ndarray:
        """(T, 2) int rows aligned with the last `step`'s output: the class of the detection each track
        matched on that frame (-1 when it coasted) and the track's voted class so far."""
        return self.tracker.output_classes()

    def matched_tracks(self) -> np.ndarray:
        """Rows (track id, x, y, w, h) of every track matched to a detection this frame, output or not."""
        return track_rows(self.tracker.matched())

    def static_tracks(self) -> np.ndarray:
        """Rows (track id, x, y, w, h) of the confirmed tracks held static this frame (kept, not output)."""
        return track_rows(self.tracker.static_outputs())


def track_rows(tracks: list[tuple[int, np.ndarray]]) -> np.ndarray:
    """(T, 5) rows (track id, x, y, w, h) of (id, box `tlwh`) pairs."""
    if not tracks:
        return np.zeros((0, 5))
    return np.array([[track_id, *box] for track_id, box in tracks])


def track_sequence(tracker: DeepSort, dets: np.ndarray) -> np.ndarray:
    """Run `tracker` over a validated detection array (`tracking.io.load_detections` layout).

    Every frame from the first to the last in `dets` is stepped, empty ones included, so tracks age
    through gaps. Returns rows (frame, id, x, y, w, h), box `tlwh` in pixels.
    """
    results = []
    for frame, rows in iter_frames(dets):
        out = tracker.step(rows[:, BOX], rows[:, CONF], rows[:, FEATURES])
        results.append(np.column_stack([np.full(len(out), frame), out]))
    return np.concatenate(results) if results else np.zeros((0, 6))
