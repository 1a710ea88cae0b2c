"""Detection-level filtering before tracking: the confidence floor and greedy non-maximum suppression."""

from __future__ import annotations

import numpy as np


def non_max_suppression(tlwh: np.ndarray, scores: np.ndarray, max_overlap: float) -> np.ndarray:
    """Indices of the boxes kept, highest score first.

    tlwh: (N, 4) boxes. Greedy: the best remaining box is kept and every other box that it covers by
    more than `max_overlap` is dropped. As in the reference DeepSORT the overlap is the intersection over
    the area of the *other* box (not IoU), with the inclusive-pixel +1 convention; with `max_overlap`
    >= 1 nothing is dropped and only the order changes.
    """
    tlwh = np.asarray(tlwh, dtype=float).reshape(-1, 4)
    order = np.argsort(scores)[::-1]  # the reference's sort, so equal scores break ties the same way
    if max_overlap >= 1.0:
        return order  # an overlap never exceeds 1
    x1, y1 = tlwh[:, 0], tlwh[:, 1]
    x2, y2 = x1 + tlwh[:, 2], y1 + tlwh[:, 3]
    area = (x2 - x1 + 1) * (y2 - y1 + 1)
    w = np.maximum(0.0, np.minimum(x2[:, None], x2[None]) - np.maximum(x1[:, None], x1[None]) + 1)
    h = np.maximum(0.0, np.minimum(y2[:, None], y2[None]) - np.maximum(y1[:, None], y1[None]) + 1)
    covers = (w * h) / area[None, :] > max_overlap  # covers[i, j]: box i suppresses box j
    suppressed = np.zeros(len(tlwh), bool)
    keep = []
    for i in order:
        if not suppressed[i]:
            keep.append(i)
            suppressed |= covers[i]
    return np.asarray(keep, dtype=int)


def filter_detections(
    tlwh: np.ndarray,
    confidence: np.ndarray,
    *,
    min_confidence: float,
    nms_max_overlap: float,
    min_detection_height: float = 0.0,
) -> np.ndarray:
    """Indices of the detections the tracker sees, in the order it sees them (highest confidence first).

    Drops detections below `min_confidence` or lower than `min_detection_height` pixels, then runs
    `non_max_suppression` with `nms_max_overlap`.
    """
    tlwh = np.asarray(tlwh, dtype=float).reshape(-1, 4)
    confidence = np.asarray(confidence, dtype=float).reshape(-1)
    candidates = np.flatnonzero((confidence >= min_confidence) & (tlwh[:, 3] >= min_detection_height))
    kept = non_max_suppression(tlwh[candidates], confidence[candidates], nms_max_overlap)
    return candidates[kept]
