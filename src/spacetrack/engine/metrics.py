"""Detection metrics on plain arrays: greedy matching, 101-point interpolated AP, precision and recall.

mAP@0.5 is the mean over classes with ground truth of the AP at IoU 0.5; mAP@0.5:0.95 also averages
over the ten IoU thresholds 0.50, 0.55, ..., 0.95 (the COCO protocol). Boxes are `xyxy` pixels.
"""

from __future__ import annotations

import numpy as np

IOU_THRESHOLDS = np.linspace(0.5, 0.95, 10)
RECALL_POINTS = np.linspace(0.0, 1.0, 101)
# `confusion_matrix`: the detections it counts and the overlap that pairs one with a target
CONFUSION_MIN_SCORE = 0.25
CONFUSION_IOU = 0.45


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU matrix (len(a), len(b)) of two `xyxy` box sets."""
    lt = np.maximum(a[:, None, :2], b[None, :, :2])
    rb = np.minimum(a[:, None, 2:4], b[None, :, 2:4])
    inter = np.clip(rb - lt, 0, None).prod(axis=2)
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    return inter / np.maximum(area_a[:, None] + area_b[None, :] - inter, 1e-12)


def match_detections(
    *boxes_scores_classes: np.ndarray, iou_thresholds: np.ndarray = IOU_THRESHOLDS
) -> np.ndarray:
    """(num_pred, num_thresholds) bool: is each detection a true positive at each IoU threshold?

    Arguments as `claimed_targets`'s: detections are taken in descending score order; each claims the
    unclaimed ground-truth box of its class with the highest IoU at or above the threshold (one image
    at a time).
    """
    return claimed_targets(*boxes_scores_classes, iou_thresholds=iou_thresholds) >= 0


def claimed_targets(
    pred_boxes: np.ndarray,
    pred_scores: np.ndarray,
    pred_classes: np.ndarray,
    gt_boxes: np.ndarray,
    gt_classes: np.ndarray,
    *,
    iou_thresholds: np.ndarray = IOU_THRESHOLDS,
) -> np.ndarray:
    """(num_pred, num_thresholds) int: the index of the ground-truth box each detection claims at each
    IoU threshold, -1 for none (the matching `match_detections` describes): pred boxes (n, 4) xyxy,
    scores (n,), classes (n,); ground-truth boxes (m, 4) xyxy, classes (m,)."""
    claims = np.full((len(pred_boxes), len(iou_thresholds)), -1, dtype=np.int64)
    if len(pred_boxes) == 0 or len(gt_boxes) == 0:
        return claims
    iou = box_iou(pred_boxes, gt_boxes) * (pred_classes[:, None] == gt_classes[None, :])
    claimed = np.zeros((len(iou_thresholds), len(gt_boxes)), dtype=bool)
    for i in np.argsort(-pred_scores, kind="stable"):
        if iou[i].max() < iou_thresholds.min():
            continue
        candidates = np.where((iou[i][None, :] >= iou_thresholds[:, None]) & ~claimed, iou[i][None, :], -1.0)
        best = candidates.argmax(axis=1)
        hit = candidates[np.arange(len(iou_thresholds)), best] >= 0
        claims[i, hit] = best[hit]
        claimed[np.flatnonzero(hit), best[hit]] = True
    return claims


def interpolated_ap(recall: np.ndarray, precision: np.ndarray) -> float:
    """Average of the precision envelope at 101 recall points (recall ascending, as from a ranked list)."""
    if len(recall) == 0:
        return 0.0
    envelope = np.maximum.accumulate(precision[::-1])[::-1]
    idx = np.searchsorted(recall, RECALL_POINTS, side="left")
    sampled = np.where(idx < len(recall), envelope[np.minimum(idx, len(recall) - 1)], 0.0)
    return float(sampled.mean())


def detection_metrics(
    tp: np.ndarray,
    scores: np.ndarray,
    pred_classes: np.ndarray,
    gt_classes: np.ndarray,
    min_score: float = 0.5,
) -> dict[str, object]:
    """mAP@0.5, mAP@0.5:0.95, precision/recall at the score threshold with the best mean F1, and
    `recall_at_score`: the fraction of ground-truth boxes found at IoU 0.5 by a detection of the right
    class scoring at least `min_score` (what a tracker with that `min_confidence` gets to see).

    `tp` (num_pred, num_thresholds) comes from `match_detections` over all images, `scores` and
    `pred_classes` are per detection, `gt_classes` per ground-truth box. Also returns, for plotting,
    `pr_curves` {class: (recall, precision) at IoU 0.5} and `score_threshold`.
    """
    found = int(tp[scores >= min_score, 0].sum()) if len(tp) else 0
    recall_at_score = found / len(gt_classes) if len(gt_classes) else 0.0
    order = np.argsort(-scores, kind="stable")
    tp, scores, pred_classes = tp[order], scores[order], pred_classes[order]
    classes = np.unique(gt_classes)
    ap = np.zeros((len(classes), tp.shape[1]))
    grid = np.linspace(0, 1, 1000)
    p_at = np.zeros((len(classes), len(grid)))
    r_at = np.zeros((len(classes), len(grid)))
    curves: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for k, c in enumerate(classes):
        mine = pred_classes == c
        num_gt = int((gt_classes == c).sum())
        hits = np.cumsum(tp[mine], axis=0)
        misses = np.cumsum(~tp[mine], axis=0)
        recall = hits / num_gt
        precision = hits / np.maximum(hits + misses, 1)
        ap[k] = [interpolated_ap(recall[:, j], precision[:, j]) for j in range(tp.shape[1])]
        curves[int(c)] = (recall[:, 0], precision[:, 0])
        if mine.any():
            # Scores descend, so interpolate on the negated scores (ascending) for each threshold.
            r_at[k] = np.interp(-grid, -scores[mine], recall[:, 0], left=0.0)
            p_at[k] = np.interp(-grid, -scores[mine], precision[:, 0], left=1.0)
    f1 = (2 * p_at * r_at / np.maximum(p_at + r_at, 1e-12)).mean(axis=0) if len(classes) else grid * 0
    best = int(f1.argmax())
    return {
        "map50": float(ap[:, 0].mean()) if len(classes) else 0.0,
        "map50_95": float(ap.mean()) if len(classes) else 0.0,
        "precision": float(p_at[:, best].mean()) if len(classes) else 0.0,
        "recall": float(r_at[:, best].mean()) if len(classes) else 0.0,
        "recall_at_score": float(recall_at_score),
        "score_threshold": float(grid[best]),
        "pr_curves": curves,
    }


def confusion_matrix(
    pred_boxes: np.ndarray,
    pred_scores: np.ndarray,
    pred_classes: np.ndarray,
    gt_boxes: np.ndarray,
    gt_classes: np.ndarray,
    num_classes: int,
    *,
    min_score: float = CONFUSION_MIN_SCORE,
    iou_threshold: float = CONFUSION_IOU,
) -> np.ndarray:
    """(num_classes + 1) x (num_classes + 1) counts of one image: row = true class, column = predicted
    class; the last row counts detections on no target (false positives), the last column targets no
    detection found (misses).

    Detections scoring at least `min_score` are paired with targets whatever their classes, the pair of
    highest IoU first, each at most once, down to `iou_threshold`: a box found under another name lands
    off the diagonal instead of counting both as a miss and as a false positive.
    """
    matrix = np.zeros((num_classes + 1, num_classes + 1), dtype=np.int64)
    keep = pred_scores >= min_score
    pred_boxes, pred_classes = pred_boxes[keep], pred_classes[keep].astype(int)
    gt_classes = gt_classes.astype(int)
    paired_pred = np.zeros(len(pred_boxes), dtype=bool)
    paired_gt = np.zeros(len(gt_boxes), dtype=bool)
    if len(pred_boxes) and len(gt_boxes):
        iou = box_iou(pred_boxes, gt_boxes)
        for flat in np.argsort(-iou, axis=None, kind="stable"):
            p, g = np.unravel_index(flat, iou.shape)
            if iou[p, g] < iou_threshold:
                break
            if paired_pred[p] or paired_gt[g]:
                continue
            paired_pred[p] = paired_gt[g] = True
            matrix[gt_classes[g], pred_classes[p]] += 1
    np.add.at(matrix, (gt_classes[~paired_gt], num_classes), 1)
    np.add.at(matrix, (num_classes, pred_classes[~paired_pred]), 1)
    return matrix
