"""Validation pass: losses, NMS, matching and mAP over a loader of letterboxed images."""

from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np
import torch
from torch import nn

from spacetrack.engine.boxes import xywh_to_xyxy
from spacetrack.engine.inference import TTA_VIEWS, augmented_predictions
from spacetrack.engine.metrics import confusion_matrix, detection_metrics, match_detections
from spacetrack.engine.nms import non_max_suppression


@torch.no_grad()
def evaluate(
    model: nn.Module,
    loader: Iterable[tuple[torch.Tensor, torch.Tensor]],
    *,
    device: torch.device,
    conf_threshold: float,
    iou_threshold: float,
    max_det: int,
    loss_fn: Callable | None = None,
    class_agnostic: bool = False,
    multi_label: bool = False,
    augment: bool = False,
    rename: Callable[[torch.Tensor, np.ndarray], np.ndarray] | None = None,
) -> tuple[dict[str, float], dict[str, object]]:
    """(metrics, details) of `model` on `loader` (see `yolo_dataset.collate` for the batch format).

    metrics: `map50`, `map50_95`, `precision`, `recall`, `recall_at_score` (recall at score >= 0.5, see
    `detection_metrics`) and, with `loss_fn`, `val_box`, `val_obj`,
    `val_cls` (per image). details: `pr_curves`, `confusion` (the `confusion_matrix` summed over the
    images, detections scoring >= `CONFUSION_MIN_SCORE`) and `examples` (the first batch's images with their
    detections and ground truth, `xyxy` pixels of the letterboxed input) for plots, and `matches`, the
    arrays `detection_metrics` took (true-positive flags, scores, predicted and true classes), so that
    the metrics of several loaders can be pooled; with `class_agnostic`, also `matches_any`, the same with
    every class as one: a box found by a detection of any class counts (the tracker follows boxes, not
    classes); with `multi_label`, also `matches_multi`, the same as `matches` from detections of every
    class an anchor scores above `conf_threshold` (see `non_max_suppression`: YOLOv5's way to measure mAP).
    The metrics themselves always come from one detection per box, the class of its best score.
    `augment`: detect with test-time augmentation (`inference.TTA_VIEWS`; the losses stay the plain
    input's). `rename`: a second stage that names the detections of one image,
    `rename(image, detections) -> classes` with the image (3, H, W) in [0, 1] and the detections (N, 6)
    `xyxy, score, class` of its pixels; its classes replace the detector's before anything is matched
    (the multi-label detections are not renamed).
    """
    model.eval()
    tps, tps_any, scores, pred_classes, gt_classes = [], [], [], [], []
    multi: list[list[np.ndarray]] = [[], [], [], []]
    num_classes = model.detect.num_classes
    confusion = np.zeros((num_classes + 1, num_classes + 1), dtype=np.int64)
    losses = torch.zeros(3)
    examples: dict[str, object] = {}
    num_images = 0
    other_views = [view for view in TTA_VIEWS if view != (1.0, False)]
    for images, targets in loader:
        x = images.to(device).float() / 255
        raw = model(x)
        if loss_fn is not None:
            losses += loss_fn([p.float() for p in raw], targets.to(device))[1].cpu() * len(x)
        decoded = model.detect.decode(raw)
        if augment:  # the plain view is decoded above; add the others
            decoded = torch.cat([decoded, augmented_predictions(model.predict, x, other_views)], dim=1)
        nms = {"conf_threshold": conf_threshold, "iou_threshold": iou_threshold, "max_det": max_det}
        detections = non_max_suppression(decoded, **nms)
        every_class = non_max_suppression(decoded, **nms, multi_label=True) if multi_label else []
        size = torch.tensor(x.shape[2:][::-1] * 2, dtype=torch.float32)
        batch_dets, batch_gts = [], []
        for i, det in enumerate(detections):
            det = det.cpu().numpy()
            if rename is not None and len(det):
                det[:, 5] = rename(x[i], det)
            mine = targets[targets[:, 0] == i]
            gt_boxes = (xywh_to_xyxy(mine[:, 2:6]) * size).numpy()
            gt_cls = mine[:, 1].numpy()
            tps.append(match_detections(det[:, :4], det[:, 4], det[:, 5], gt_boxes, gt_cls))
            confusion += confusion_matrix(det[:, :4], det[:, 4], det[:, 5], gt_boxes, gt_cls, num_classes)
            if class_agnostic:
                one = np.zeros(len(det)), np.zeros(len(gt_cls))
                tps_any.append(match_detections(det[:, :4], det[:, 4], one[0], gt_boxes, one[1]))
            if multi_label:
                m = every_class[i].cpu().numpy()
                hit = match_detections(m[:, :4], m[:, 4], m[:, 5], gt_boxes, gt_cls)
                for part, a in zip(multi, (hit, m[:, 4], m[:, 5], gt_cls), strict=True):
                    part.append(a)
            scores.append(det[:, 4])
            pred_classes.append(det[:, 5])
            gt_classes.append(gt_cls)
            batch_dets.append(det)
            batch_gts.append(np.column_stack((gt_boxes, gt_cls)))
        if not examples:
            examples = {"images": images.numpy(), "detections": batch_dets, "ground_truth": batch_gts}
        num_images += len(x)
    matches = tuple(np.concatenate(a) for a in (tps, scores, pred_classes, gt_classes))
    result = detection_metrics(*matches)
    metrics = {k: float(result[k]) for k in ("map50", "map50_95", "precision", "recall", "recall_at_score")}
    if loss_fn is not None:
        metrics.update(zip(("val_box", "val_obj", "val_cls"), (losses / num_images).tolist(), strict=True))
    details = {"pr_curves": result["pr_curves"], "examples": examples, "matches": matches,
               "confusion": confusion}  # fmt: skip
    if class_agnostic:
        tp, found, pred, truth = matches
        details["matches_any"] = (np.concatenate(tps_any), found, np.zeros_like(pred), np.zeros_like(truth))
    if multi_label:
        details["matches_multi"] = tuple(np.concatenate(a) for a in multi)
    return metrics, details
