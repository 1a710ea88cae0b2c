"""Turn decoded detector outputs into final detections with torchvision's batched NMS."""

from __future__ import annotations

import torch
from torchvision.ops import batched_nms

from spacetrack.engine.boxes import xywh_to_xyxy

SCORES = ("class", "objectness")  # a detection's score: objectness x best class probability | objectness


def check_score(score: str, key: str = "score") -> None:
    """A ValueError naming `key` unless `score` is one of `SCORES`."""
    if score not in SCORES:
        raise ValueError(f"{key} must be one of {', '.join(SCORES)}, got {score!r}")


def non_max_suppression(
    pred: torch.Tensor,
    *,
    conf_threshold: float = 0.001,
    iou_threshold: float = 0.6,
    max_det: int = 300,
    multi_label: bool = False,
    score: str = "class",
    agnostic: bool = False,
    probabilities: bool = False,
) -> list[torch.Tensor]:
    """Per image an (n, 6) tensor `x1, y1, x2, y2, score, class` (xyxy pixels), best score first.

    `pred` is `YOLOv5.predict` output (B, N, 5 + classes). The score is objectness times the best
    class probability (objectness alone with one class, whose class output is never trained). NMS is
    per class. With `multi_label`, an anchor gives a detection for every class whose objectness times
    class probability passes `conf_threshold`, not only for its best one: a box the model is unsure how
    to name then also counts, at its lower score, for its second class (how YOLOv5 measures mAP); the
    tracker takes one class per box (the default).

    `score="objectness"` scores each box by its objectness alone, still named by its best class: whether
    there is a target at all, however the model splits it between classes (for a tracker that follows
    every class alike). Not with `multi_label`.

    `agnostic`: NMS over every class at once, so a target the model names two ways keeps one box, its
    best-scored (what a tracker that follows every class alike wants); per class by default (YOLOv5's
    validation, and the mAP).

    `probabilities`: each row also carries what its anchor predicted, `objectness, p_1 .. p_C` (n, 7 + C),
    for a step after NMS that weighs the classes itself. Not with `multi_label`.
    """
    check_score(score)
    if multi_label and score != "class":
        raise ValueError("multi_label detections are scored by class (score='class')")
    if multi_label and probabilities:
        raise ValueError("multi_label detections do not carry their anchor's probabilities")
    out = []
    by_class = score == "class"
    num_classes = pred.shape[2] - 5
    for p in pred:
        if num_classes > 1 and multi_label:
            anchor, cls = (p[:, 4:5] * p[:, 5:] > conf_threshold).nonzero(as_tuple=True)
            conf = p[anchor, 4] * p[anchor, 5 + cls]
            boxes = xywh_to_xyxy(p[anchor, :4])
        else:
            if num_classes > 1:
                cls_score, cls = p[:, 5:].max(dim=1)
                conf = p[:, 4] * cls_score if by_class else p[:, 4]
            else:
                conf = p[:, 4]
                cls = torch.zeros_like(conf, dtype=torch.long)
            keep = conf > conf_threshold
            boxes, conf, cls = xywh_to_xyxy(p[keep, :4]), conf[keep], cls[keep]
            extra = p[keep, 4:] if probabilities else None
        groups = torch.zeros_like(cls) if agnostic else cls
        kept = batched_nms(boxes.float(), conf.float(), groups, iou_threshold)[:max_det]
        rows = [boxes[kept], conf[kept, None], cls[kept, None].to(boxes.dtype)]
        out.append(torch.cat(rows + [extra[kept]] if probabilities else rows, dim=1))
    return out
