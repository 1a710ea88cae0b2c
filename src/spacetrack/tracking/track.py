"""One track's bookkeeping: its Kalman state, hit/miss counters, life cycle and pending features."""

from __future__ import annotations

from enum import IntEnum

import numpy as np

from spacetrack.tracking.dynamic import MotionEvidence


class TrackState(IntEnum):
    """Tentative until `n_init` hits, then confirmed; deleted on a tentative miss or after `max_age`."""

    TENTATIVE = 1
    CONFIRMED = 2
    DELETED = 3


class Track:
    """A target hypothesis with state mean (8,) and covariance (8, 8) in `xyah` + velocities.

    `features` holds the appearance features gathered since they were last handed to the metric
    (tentative tracks keep theirs until they are confirmed); `evidence` its motion evidence when the
    tracker decides per track what moves (`tracking.dynamic`), else None.
    """

    def __init__(
        self,
        mean: np.ndarray,
        covariance: np.ndarray,
        track_id: int,
        *,
        n_init: int,
        max_age: int,
        feature: np.ndarray | None = None,
    ) -> None:
        self.mean = mean
        self.covariance = covariance
        self.track_id = track_id
        self.hits = 1
        self.age = 1
        self.time_since_update = 0
        self.state = TrackState.TENTATIVE
        self.features: list[np.ndarray] = [] if feature is None else [feature]
        self.evidence: MotionEvidence | None = None
        self.detection_tlwh: np.ndarray | None = None  # the box `tlwh` of its last matched detection
        self.detection_class = -1  # that detection's class index (-1: unknown)
        self.whole_area: float | None = None  # its box's area when last seen whole (`Tracker.occluded_area`)
        self._n_init = n_init
        self._max_age = max_age

    def predicted(self, mean: np.ndarray, covariance: np.ndarray) -> None:
        """Take the state predicted one frame ahead."""
        self.mean, self.covariance = mean, covariance
        self.age += 1
        self.time_since_update += 1

    def hit(self, mean: np.ndarray, covariance: np.ndarray, feature: np.ndarray | None) -> None:
        """Take the state corrected by a matched detection, and that detection's feature."""
        self.mean, self.covariance = mean, covariance
        if feature is not None:
            self.features.append(feature)
        self.hits += 1
        self.time_since_update = 0
        if self.state == TrackState.TENTATIVE and self.hits >= self._n_init:
            self.state = TrackState.CONFIRMED

    def mark_missed(self) -> None:
        """No detection this frame: a tentative track dies at once, a confirmed one after `max_age`."""
        if self.state == TrackState.TENTATIVE or self.time_since_update > self._max_age:
            self.state = TrackState.DELETED

    def is_tentative(self) -> bool:
        return self.state == TrackState.TENTATIVE

    def is_confirmed(self) -> bool:
        return self.state == TrackState.CONFIRMED

    def is_deleted(self) -> bool:
        return self.state == TrackState.DELETED
