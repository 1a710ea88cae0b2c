"""The detections of one frame, as arrays: boxes `tlwh`, confidences and appearance features."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def tlwh_to_xyah(tlwh: np.ndarray) -> np.ndarray:
    """(..., 4) boxes `tlwh` (top-left x, y, width, height; pixels) -> `xyah` (centre, aspect w/h, height)."""
    tlwh = np.asarray(tlwh, dtype=float)
    x, y, w, h = np.moveaxis(tlwh, -1, 0)
    return np.stack([x + w / 2, y + h / 2, w / h, h], -1)


def xyah_to_tlwh(xyah: np.ndarray) -> np.ndarray:
    """(..., 4) boxes `xyah` -> `tlwh`."""
    xyah = np.asarray(xyah, dtype=float)
    cx, cy, a, h = np.moveaxis(xyah, -1, 0)
    w = a * h
    return np.stack([cx - w / 2, cy - h / 2, w, h], -1)


@dataclass(frozen=True)
class Detections:
    """N detections of one frame.

    tlwh: (N, 4) boxes in pixels; confidence: (N,); feature: (N, D) appearance vectors, L2-normalised
    here so that the cosine distance is 1 - dot product (D may be 0 when no appearance is used).
    """

    tlwh: np.ndarray
    confidence: np.ndarray
    feature: np.ndarray

    @classmethod
    def create(
        cls, tlwh: np.ndarray, confidence: np.ndarray, feature: np.ndarray | None = None
    ) -> Detections:
        tlwh = np.asarray(tlwh, dtype=float).reshape(-1, 4)
        confidence = np.asarray(confidence, dtype=float).reshape(-1)
        if feature is None:
            feature = np.zeros((len(tlwh), 0))
        feature = np.asarray(feature, dtype=float).reshape(len(tlwh), -1)
        if feature.shape[1]:
            norm = np.linalg.norm(feature, axis=1, keepdims=True)
            feature = feature / np.where(norm > 0, norm, 1.0)
        return cls(tlwh, confidence, feature)

    def __len__(self) -> int:
        return len(self.tlwh)

    def subset(self, index: np.ndarray) -> Detections:
        """The detections at positions `index`, in that order."""
        index = np.asarray(index, dtype=int)
        return Detections(self.tlwh[index], self.confidence[index], self.feature[index])

    def to_xyah(self) -> np.ndarray:
        return tlwh_to_xyah(self.tlwh)
