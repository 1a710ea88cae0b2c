"""The detections of one frame, as arrays: boxes `tlwh`, confidences and appearance features."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spacetrack.tracking.class_vote import UNKNOWN


def tlwh_to_xyah(tlwh: np.ndarray) -> np.ndarray:
    """(..., 4) boxes `tlwh` (top-left x, y, width, height; pixels) -> `xyah` (centre, aspect w/h, height)."""
    xyah = np.array(tlwh, dtype=float)
    xyah[..., :2] += xyah[..., 2:] / 2
    xyah[..., 2] /= xyah[..., 3]
    return xyah


def xyah_to_tlwh(xyah: np.ndarray) -> np.ndarray:
    """(..., 4) boxes `xyah` -> `tlwh`."""
    tlwh = np.array(xyah, dtype=float)
    tlwh[..., 2] *= tlwh[..., 3]
    tlwh[..., :2] -= tlwh[..., 2:] / 2
    return tlwh


@dataclass(frozen=True)
class Detections:
    """N detections of one frame.

    tlwh: (N, 4) boxes in pixels; confidence: (N,); feature: (N, D) appearance vectors (None: D = 0),
    L2-normalised here so that the cosine distance is 1 - dot product (D may be 0 when no appearance is used);
    dynamic: (N,) bool, whether a motion blob of the frame matched the box (None: all True), the evidence
    of the track-level dynamic decision (`tracking.dynamic`); classes: (N,) the detector's class index of
    each box (None: all -1, unknown), what a track's class vote (`Tracker.votes`) counts.
    """

    tlwh: np.ndarray
    confidence: np.ndarray
    feature: np.ndarray
    dynamic: np.ndarray
    classes: np.ndarray

    @classmethod
    def create(
        cls,
        tlwh: np.ndarray,
        confidence: np.ndarray,
        feature: np.ndarray | None = None,
        dynamic: np.ndarray | None = None,
        classes: np.ndarray | None = None,
    ) -> Detections:
        tlwh = np.asarray(tlwh, dtype=float).reshape(-1, 4)
        confidence = np.asarray(confidence, dtype=float).reshape(-1)
        if feature is None:
            feature = np.zeros((len(tlwh), 0))
        feature = np.asarray(feature, dtype=float)
        if feature.shape[1]:
            norm = np.linalg.norm(feature, axis=1, keepdims=True)
            feature = feature / np.where(norm > 0, norm, 1.0)
        dynamic = np.ones(len(tlwh), bool) if dynamic is None else np.asarray(dynamic, dtype=bool).reshape(-1)
        classes = (
            np.full(len(tlwh), UNKNOWN) if classes is None else np.asarray(classes).astype(int).reshape(-1)
        )
        return cls(tlwh, confidence, feature, dynamic, classes)

    def __len__(self) -> int:
        return len(self.tlwh)

    def subset(self, index: np.ndarray) -> Detections:
        """The detections at positions `index`, in that order."""
        index = np.asarray(index, dtype=int)
        return Detections(
            self.tlwh[index],
            self.confidence[index],
            self.feature[index],
            self.dynamic[index],
            self.classes[index],
        )

    def concat(self, other: Detections) -> Detections:
        """These detections followed by `other`'s (features of the same dimension)."""
        return Detections(
            np.concatenate([self.tlwh, other.tlwh]),
            np.concatenate([self.confidence, other.confidence]),
            np.concatenate([self.feature, other.feature]),
            np.concatenate([self.dynamic, other.dynamic]),
            np.concatenate([self.classes, other.classes]),
        )

    def to_xyah(self) -> np.ndarray:
        return tlwh_to_xyah(self.tlwh)
