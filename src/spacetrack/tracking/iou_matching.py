"""Intersection over union of boxes `tlwh`, as a whole matrix."""

from __future__ import annotations

import numpy as np


def intersections(a_tlwh: np.ndarray, b_tlwh: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N, M) intersection areas of boxes a and b (tlwh pixels), with the (N,) and (M,) box areas."""
    a = np.asarray(a_tlwh, dtype=np.float64).reshape(-1, 4)
    b = np.asarray(b_tlwh, dtype=np.float64).reshape(-1, 4)
    x1 = np.maximum(a[:, None, 0], b[None, :, 0])
    y1 = np.maximum(a[:, None, 1], b[None, :, 1])
    x2 = np.minimum(a[:, None, 0] + a[:, None, 2], b[None, :, 0] + b[None, :, 2])
    y2 = np.minimum(a[:, None, 1] + a[:, None, 3], b[None, :, 1] + b[None, :, 3])
    inter = np.clip(x2 - x1, 0, None) * np.clip(y2 - y1, 0, None)
    return inter, a[:, 2] * a[:, 3], b[:, 2] * b[:, 3]


def iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, M) IoU between boxes `a` (N, 4) and `b` (M, 4), both `tlwh` in pixels; 0 where disjoint."""
    inter, area_a, area_b = intersections(a, b)
    union = area_a[:, None] + area_b[None, :] - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=inter > 0)
