"""The multi-target tracker: predict, associate (cascade on eq. 15, then IoU), update, manage tracks.

Beyond the reference: `predict` can move every prediction by the camera's scene shift of the frame
(camera-motion compensation as BoT-SORT does it, here a translation); with `dynamics` the tracker
decides per track what moves and outputs only the dynamic tracks (`tracking.dynamic`); with
`reacquire_gate` a confirmed track that neither stage matched gets a last chance by where its Kalman
filter expects it. With none of them, it is the reference DeepSORT.

Why the last stage: a target that comes out from behind an occluder reappears as a small, partly visible
box whose appearance is far from the features its track gathered, so the cascade's appearance gate turns
it away, and the IoU stage only serves tracks lost one frame ago. The reference then starts a new track
(an identity switch) although the detection lies where the old track predicts it.
"""

from __future__ import annotations

import numpy as np

from spacetrack.tracking.class_vote import UNKNOWN, ClassVotes
from spacetrack.tracking.detection import Detections, xyah_to_tlwh
from spacetrack.tracking.dynamic import TrackDynamics
from spacetrack.tracking.iou_matching import iou_matrix
from spacetrack.tracking.kalman_filter import CHI2_95_4DOF, KalmanFilter
from spacetrack.tracking.linear_assignment import INFTY_COST, matching_cascade, min_cost_matching
from spacetrack.tracking.nn_matching import NearestNeighborDistanceMetric
from spacetrack.tracking.track import Track

OUTPUT_BOXES = ("state", "detection")


class Tracker:
    """DeepSORT's association and track management over a stream of frames.

    metric: the appearance metric (eq. 13), or None to associate by IoU alone (SORT).
    max_iou_distance: largest 1 - IoU accepted in the IoU stage.
    max_age: frames a confirmed track may go unmatched before it is deleted (also the cascade depth).
    n_init: hits that confirm a tentative track.
    lambda_: weight of the Mahalanobis distance in eq. (15); 0 is the original DeepSORT, where motion
        only gates and appearance alone ranks.
    gating_threshold: Mahalanobis gate t(1) of eq. (12) (0.95 chi-square quantile, 4 dof).
    dynamics: decide per track whether it moves and output only the tracks that do; None outputs every
        confirmed track (the reference).
    output_box: "state", the Kalman state's box (the reference); "detection", the box of the detection
        matched in this frame (the state's box on a frame without one).
    reacquire_gate: after the cascade and the IoU stage, the confirmed tracks still unmatched and the
        detections left are assigned (Hungarian) on the squared Mahalanobis distance of the box centre
        alone, pairs above this gate rejected (the chi-square quantiles of 2 degrees of freedom:
        5.99 for 0.95, 13.8 for 0.999);
        None: no such stage (the reference).
    coast_in_view: a confirmed track unmatched on this frame (output on its prediction, the reference's
        rule) is output only while the predicted box lies wholly inside the image, so a target that has
        just left the frame leaves no box behind; needs the frame size given to `update`. False: the
        reference.
    occluded_area: in (0, 1); a matched box under this share of the area its track had when last seen
        whole (its last box at or above that share) keeps the track alive but leaves its Kalman state as
        predicted, since a box an occluder cuts short moves its centre with the occluder's edge. None:
        every match updates the state (the reference).
    """

    def __init__(
        self,
        *,
        metric: NearestNeighborDistanceMetric | None,
        max_iou_distance: float = 0.7,
        max_age: int = 70,
        n_init: int = 3,
        lambda_: float = 0.0,
        gating_threshold: float = CHI2_95_4DOF,
        dynamics: TrackDynamics | None = None,
        output_box: str = "state",
        reacquire_gate: float | None = None,
        coast_in_view: bool = False,
        occluded_area: float | None = None,
    ) -> None:
        if occluded_area is not None and not 0.0 < occluded_area < 1.0:
            raise ValueError(f"tracker.occluded_area must lie in (0, 1) or be null, got {occluded_area}")
        if not 0.0 <= lambda_ <= 1.0:
            raise ValueError(f"lambda_ must lie in [0, 1], got {lambda_}")
        if output_box not in OUTPUT_BOXES:
            raise ValueError(f"tracker.output_box must be one of {OUTPUT_BOXES}, got {output_box!r}")
        if reacquire_gate is not None and not reacquire_gate > 0:
            raise ValueError(f"tracker.reacquire_gate must be > 0 or null, got {reacquire_gate}")
        self.output_box = output_box
        self.reacquire_gate = reacquire_gate
        self.coast_in_view = bool(coast_in_view)
        self.occluded_area = occluded_area
        self.metric = metric
        self.max_iou_distance = max_iou_distance
        self.max_age = max_age
        self.n_init = n_init
        self.lambda_ = lambda_
        self.gating_threshold = gating_threshold
        self.dynamics = dynamics
        self.kf = KalmanFilter()
        self.tracks: list[Track] = []
        self.votes = ClassVotes()  # each track's class, voted over its matched detections
        self._shown: list[Track] = []  # the tracks of the last `outputs()`, in its order
        self._next_id = 1
        self._camera_moving = False
        self._frame_size: tuple[int, int] | None = None

    def predict(self, shift: tuple[float, float] = (0.0, 0.0)) -> None:
        """Move every track one frame ahead (call once per frame, before `update`).

        shift: how far (x, y pixels) the scene moved in the image since the previous frame; each predicted
        box centre moves with it, so the velocities learn the motion against the scene.
        """
        if not self.tracks:
            return
        means, covs = self.kf.predict(*self._states(self.tracks))
        if shift[0] or shift[1]:
            means[:, :2] += shift
        for track, mean, cov in zip(self.tracks, means, covs, strict=True):
            track.predicted(mean, cov)

    def update(
        self,
        detections: Detections,
        offset: tuple[float, float] = (0.0, 0.0),
        *,
        camera_moving: bool = False,
        frame_size: tuple[int, int] | None = None,
        low: Detections | None = None,
        weak: np.ndarray | None = None,
    ) -> None:
        """Associate this frame's `detections`, update matched tracks, age the others, start new ones.

        offset: the scene's displacement (x, y pixels) in this frame since the first one, for the motion
        evidence of `dynamics`; camera_moving: whether the camera has been found moving (`dynamics` may
        then stop trusting the blobs); frame_size: the image's (width, height), if known.
        low: beyond the reference, low-scored detections offered last, by box overlap (1 - IoU at most
        `max_iou_distance`, the track's predicted box however long it has gone unmatched), to the confirmed
        tracks that no stage matched (ByteTrack's second association: a target the detector scores low for
        a few frames keeps its track instead of leaving a gap); they add no appearance feature and start
        no track.
        weak: (N,) bool over `detections`, those kept below the usual floor (`DeepSort`'s motion_confirm):
        one the first stages leave unmatched joins `low` in the last association before it may start a
        track, so that a box the low-scored ones' rule would have given to a confirmed track still goes
        to it.
        """
        self._camera_moving, self._frame_size = camera_moving, frame_size
        matches, unmatched_tracks, unmatched_detections = self._match(detections)
        low_matches: list[tuple[int, int]] = []
        offered = [] if weak is None else [d for d in unmatched_detections if weak[d]]
        first_offered = 0 if low is None else len(low)  # their positions in `low` from here
        if offered:
            extra = detections.subset(np.array(offered))
            low = extra if low is None else low.concat(extra)
        if low is not None and len(low):
            confirmed = [k for k in unmatched_tracks if self.tracks[k].is_confirmed()]
            low_matches, _, _ = min_cost_matching(
                lambda t, d: self._iou_cost(low, t, d, recent_only=False),
                self.max_iou_distance,
                confirmed,
                list(range(len(low))),
            )
            taken = {k for k, _ in low_matches}
            unmatched_tracks = [k for k in unmatched_tracks if k not in taken]
            if offered:
                given = {offered[d - first_offered] for _, d in low_matches if d >= first_offered}
                unmatched_detections = [d for d in unmatched_detections if d not in given]
        self._update_matched(matches, detections, offset, features=True)
        self._update_matched(low_matches, low, offset, features=False)
        for i in unmatched_tracks:
            self.tracks[i].mark_missed()
        for d in unmatched_detections:
            self._initiate_track(detections, d)
            self._observe(self.tracks[-1], detections, d, offset)
        self.tracks = [t for t in self.tracks if not t.is_deleted()]
        if self.metric is not None:
            self._fit_metric()

    def _update_matched(
        self,
        matches: list[tuple[int, int]],
        detections: Detections,
        offset: tuple[float, float],
        *,
        features: bool,
    ) -> None:
        """Correct each matched track by its detection; `features`: also gather the detection's appearance."""
        if not matches:
            return
        t_idx, d_idx = map(list, zip(*matches, strict=True))
        tracks = [self.tracks[i] for i in t_idx]
        predicted = self._states(tracks)
        means, covs = self.kf.update(*predicted, detections.subset(d_idx).to_xyah())
        if self.occluded_area is not None:
            self._hold_occluded(tracks, detections.tlwh[d_idx], predicted, means, covs)
        use_features = features and self.metric is not None
        for track, mean, cov, d in zip(tracks, means, covs, d_idx, strict=True):
            track.hit(mean, cov, detections.feature[d] if use_features else None)
            self._observe(track, detections, d, offset)

    def outputs(self) -> list[tuple[int, np.ndarray]]:
        """(track id, box `tlwh`) of the confirmed tracks matched this frame or the one before.

        The box is the filtered state, not the detection (the reference DeepSORT's output rule). With
        `dynamics`, only the tracks it found dynamic.
        """
        listed, self._shown = self._listed(dynamic=True)
        return listed

    def output_classes(self) -> np.ndarray:
        """(T, 2) int rows for the tracks of the last `outputs()`, in its order: the class of the
        detection each matched on that frame (UNKNOWN when it coasted) and the track's voted class."""
        rows = [
            (t.detection_class if t.time_since_update == 0 else UNKNOWN, self.votes.winner(t.track_id)[0])
            for t in self._shown
        ]
        return np.array(rows, dtype=int).reshape(-1, 2)

    def static_outputs(self) -> list[tuple[int, np.ndarray]]:
        """Like `outputs`, the confirmed tracks that `dynamics` holds static (none without it)."""
        return self._listed(dynamic=False)[0] if self.dynamics is not None else []

    def matched(self) -> list[tuple[int, np.ndarray]]:
        """(track id, box `tlwh` of its detection) of every track matched this frame, tentative, static
        and output alike: what offline backfill (`tracking.offline`) gives back to the tracks output later."""
        return [(t.track_id, t.detection_tlwh) for t in self.tracks if t.time_since_update == 0]

    def _listed(self, *, dynamic: bool) -> tuple[list[tuple[int, np.ndarray]], list[Track]]:
        """(track id, box) of the confirmed tracks shown this frame, and those tracks."""
        shown = [
            t
            for t in self.tracks
            if t.is_confirmed()
            and t.time_since_update <= 1
            and (t.evidence is None or t.evidence.dynamic == dynamic)
        ]
        boxes = self._boxes(shown)
        if self.output_box == "detection":
            for i, t in enumerate(shown):
                if t.time_since_update == 0:
                    boxes[i] = t.detection_tlwh
        if self.coast_in_view and self._frame_size is not None:
            kept = [
                t.time_since_update != 1 or _inside(box, self._frame_size)
                for t, box in zip(shown, boxes, strict=True)
            ]
            shown, boxes = (
                [t for t, k in zip(shown, kept, strict=True) if k],
                boxes[np.array(kept, dtype=bool)],
            )
        return [(t.track_id, box) for t, box in zip(shown, boxes, strict=True)], shown

    def _hold_occluded(
        self,
        tracks: list[Track],
        tlwh: np.ndarray,
        predicted: tuple[np.ndarray, np.ndarray],
        means: np.ndarray,
        covs: np.ndarray,
    ) -> None:
        """Keep the predicted state of each track whose matched box is under `occluded_area` of the area
        it had when last seen whole: a box cut short by an occluder moves with the occluder's edge, not
        with the target, so it tells that the target is there but not where it goes."""
        areas = tlwh[:, 2] * tlwh[:, 3]
        for i, (track, area) in enumerate(zip(tracks, areas, strict=True)):
            if track.whole_area is not None and area < self.occluded_area * track.whole_area:
                means[i], covs[i] = predicted[0][i], predicted[1][i]
            else:
                track.whole_area = float(area)

    def _observe(self, track: Track, detections: Detections, d: int, offset: tuple[float, float]) -> None:
        """Note the detection `d` matched to `track`: its box, its class vote and the track's motion evidence."""
        track.detection_tlwh = detections.tlwh[d]
        track.detection_class = int(detections.classes[d])
        self.votes.add(track.track_id, track.detection_class, detections.confidence[d])
        if self.dynamics is None:
            return
        if track.evidence is None:
            track.evidence = self.dynamics.new_evidence()
        self.dynamics.observe(
            track.evidence,
            detections.tlwh[d],
            offset,
            detections.dynamic[d],
            camera_moving=self._camera_moving,
            frame_size=self._frame_size,
        )

    @staticmethod
    def _boxes(tracks: list[Track]) -> np.ndarray:
        """(T, 4) boxes `tlwh` of the tracks' current states."""
        return xyah_to_tlwh(np.array([t.mean[:4] for t in tracks]).reshape(-1, 4))

    @staticmethod
    def _states(tracks: list[Track]) -> tuple[np.ndarray, np.ndarray]:
        return np.stack([t.mean for t in tracks]), np.stack([t.covariance for t in tracks])

    def _initiate_track(self, detections: Detections, d: int) -> None:
        mean, cov = self.kf.initiate(detections.to_xyah()[d])
        feature = detections.feature[d] if self.metric is not None else None
        self.tracks.append(
            Track(mean, cov, self._next_id, n_init=self.n_init, max_age=self.max_age, feature=feature)
        )
        self._next_id += 1

    def _fit_metric(self) -> None:
        """Hand the confirmed tracks' new features to the metric; it forgets every other track."""
        confirmed = [t for t in self.tracks if t.is_confirmed()]
        pending = [(f, t.track_id) for t in confirmed for f in t.features]
        for t in confirmed:
            t.features = []
        features = np.array([f for f, _ in pending]) if pending else np.zeros((0, 0))
        targets = np.array([k for _, k in pending], dtype=int)
        self.metric.partial_fit(features, targets, [t.track_id for t in confirmed])

    def _appearance_cost(
        self, detections: Detections, track_idx: list[int], det_idx: list[int]
    ) -> np.ndarray:
        """Eq. (15) over the pairs, with pairs outside either gate (eqs. 12, 14) set to INFTY_COST."""
        tracks = [self.tracks[i] for i in track_idx]
        mahalanobis = self.kf.gating_distance(*self._states(tracks), detections.subset(det_idx).to_xyah())
        inside = mahalanobis <= self.gating_threshold
        # Pairs outside the motion gate can never match, so their appearance is not even computed.
        cosine = self.metric.distance(detections.feature[det_idx], [t.track_id for t in tracks], inside)
        admissible = inside & (cosine <= self.metric.matching_threshold)
        cost = np.full(mahalanobis.shape, INFTY_COST)
        cost[admissible] = self.lambda_ * mahalanobis[admissible] + (1.0 - self.lambda_) * cosine[admissible]
        return cost

    def _iou_cost(
        self, detections: Detections, track_idx: list[int], det_idx: list[int], *, recent_only: bool = True
    ) -> np.ndarray:
        """1 - IoU between track states and detections; with `recent_only`, tracks unseen for over a frame
        never match."""
        tracks = [self.tracks[i] for i in track_idx]
        cost = 1.0 - iou_matrix(self._boxes(tracks), detections.tlwh[det_idx])
        if recent_only:
            cost[np.array([t.time_since_update > 1 for t in tracks])] = INFTY_COST
        return cost

    def _position_cost(self, detections: Detections, track_idx: list[int], det_idx: list[int]) -> np.ndarray:
        """Squared Mahalanobis distance of the detections' box centres to the tracks' predicted ones."""
        tracks = [self.tracks[i] for i in track_idx]
        xyah = detections.subset(det_idx).to_xyah()
        return self.kf.gating_distance(*self._states(tracks), xyah, only_position=True)

    def _match(self, detections: Detections) -> tuple[list[tuple[int, int]], list[int], list[int]]:
        confirmed = [i for i, t in enumerate(self.tracks) if t.is_confirmed()]
        unconfirmed = [i for i, t in enumerate(self.tracks) if not t.is_confirmed()]
        all_detections = list(range(len(detections)))
        if self.metric is None:
            matches_a, unmatched_a, unmatched_detections = [], confirmed, all_detections
        else:
            # Admissible pairs cost at most this (both gates passed), so it is the acceptance threshold.
            max_cost = (
                self.lambda_ * self.gating_threshold + (1 - self.lambda_) * self.metric.matching_threshold
            )
            matches_a, unmatched_a, unmatched_detections = matching_cascade(
                lambda t, d: self._appearance_cost(detections, t, d),
                max_cost,
                self.max_age,
                confirmed,
                [self.tracks[i].time_since_update for i in confirmed],
                all_detections,
            )
        # Tracks lost just now, and tentative ones, get a second chance by box overlap alone.
        iou_candidates = unconfirmed + [k for k in unmatched_a if self.tracks[k].time_since_update == 1]
        unmatched_a = [k for k in unmatched_a if self.tracks[k].time_since_update != 1]
        matches_b, unmatched_b, unmatched_detections = min_cost_matching(
            lambda t, d: self._iou_cost(detections, t, d),
            self.max_iou_distance,
            iou_candidates,
            unmatched_detections,
        )
        unmatched = sorted(set(unmatched_a + unmatched_b))
        if self.reacquire_gate is None:
            return matches_a + matches_b, unmatched, unmatched_detections
        lost = [k for k in unmatched if self.tracks[k].is_confirmed()]
        matches_c, _, unmatched_detections = min_cost_matching(
            lambda t, d: self._position_cost(detections, t, d),
            self.reacquire_gate,
            lost,
            unmatched_detections,
        )
        taken = {k for k, _ in matches_c}
        return (
            matches_a + matches_b + matches_c,
            [k for k in unmatched if k not in taken],
            unmatched_detections,
        )


def _inside(tlwh: np.ndarray, frame_size: tuple[int, int]) -> bool:
    """Whether the box lies wholly inside a frame of `frame_size` (width, height)."""
    x, y, w, h = tlwh
    return x >= 0 and y >= 0 and x + w <= frame_size[0] and y + h <= frame_size[1]
