"""Box conversions and the complete IoU (CIoU) used by the box loss."""

from __future__ import annotations

import math

import torch


def xywh_to_xyxy(boxes: torch.Tensor) -> torch.Tensor:
    """(..., 4) centre `cx, cy, w, h` -> corners `x1, y1, x2, y2` (same units)."""
    xy, wh = boxes[..., :2], boxes[..., 2:4] / 2
    return torch.cat((xy - wh, xy + wh), dim=-1)


def ciou(pred: torch.Tensor, target: torch.Tensor, eps: float = 1e-7) -> torch.Tensor:
    """Complete IoU of matching rows of two (N, 4) `cx, cy, w, h` box sets, shape (N,).

    IoU minus the squared centre distance over the squared diagonal of the enclosing box, minus an
    aspect-ratio consistency term (Zheng et al., 2020). 1 for identical boxes, down to -1.5.
    """
    p1, p2 = xywh_to_xyxy(pred).split(2, dim=-1)
    t1, t2 = xywh_to_xyxy(target).split(2, dim=-1)
    wh_p = pred[:, 2:4]
    wh_t = target[:, 2:4]
    inter = (torch.min(p2, t2) - torch.max(p1, t1)).clamp(min=0).prod(dim=-1)
    union = wh_p.prod(dim=-1) + wh_t.prod(dim=-1) - inter + eps
    iou = inter / union
    enclose = torch.max(p2, t2) - torch.min(p1, t1)
    diagonal2 = enclose.pow(2).sum(dim=-1) + eps
    centre2 = (pred[:, :2] - target[:, :2]).pow(2).sum(dim=-1)
    v = (4 / math.pi**2) * (
        torch.atan(wh_t[:, 0] / (wh_t[:, 1] + eps)) - torch.atan(wh_p[:, 0] / (wh_p[:, 1] + eps))
    ).pow(2)
    # The trade-off weight is treated as a constant, as in the CIoU paper's gradient derivation.
    with torch.no_grad():
        alpha = v / (v - iou + (1 + eps))
    return iou - (centre2 / diagonal2 + v * alpha)
