"""YOLOv5 loss: anchor matching with a size-ratio limit and neighbour cells, CIoU box loss, objectness
with the IoU as target, per-level balance, BCE classification.

Targets are an (M, 6) tensor of rows `image_index, class, cx, cy, w, h` with the box normalised to
the network input (0-1). Predictions are the raw per-level outputs of `Detect.forward`.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from spacetrack.engine.boxes import ciou

# The five candidate cells of a target: its own and the two nearest of its four neighbours.
_NEIGHBOUR_OFFSETS = torch.tensor([[0, 0], [1, 0], [0, 1], [-1, 0], [0, -1]], dtype=torch.float32)


class YoloLoss:
    """Weighted sum of box, objectness and class losses, times the batch size.

    The gains are the reference ones for 3 levels, 80 classes and 640-pixel inputs; they are rescaled
    here for the actual number of levels, classes and `image_size` (pixels) so that one set of keys
    works at every input size. The objectness target of a matched anchor is `(1 - iou_ratio) +
    iou_ratio * IoU` (YOLOv5's `gr`; 1.0: the IoU itself, so small boxes, whose IoU is lower, learn
    lower scores).
    """

    def __init__(
        self,
        *,
        anchors: torch.Tensor,
        strides: torch.Tensor,
        num_classes: int,
        image_size: int,
        box: float = 0.05,
        obj: float = 1.0,
        cls: float = 0.5,
        anchor_t: float = 4.0,
        balance: Sequence[float] = (4.0, 1.0, 0.4),
        balance_p2: float = 16.0,
        iou_ratio: float = 1.0,
    ) -> None:
        if not 0 <= iou_ratio <= 1:
            raise ValueError(f"loss.iou_ratio must lie in [0, 1], got {iou_ratio}")
        self.iou_ratio = iou_ratio
        num_levels = len(anchors)
        if num_levels == len(balance) + 1:  # a stride-4 level, last in the head (models.yolo, p2)
            balance = (*balance, balance_p2)
        if len(balance) != num_levels:
            raise ValueError(f"balance has {len(balance)} entries for {num_levels} detection levels")
        # Anchors in grid units of their own level.
        self.anchors = anchors / strides.view(-1, 1, 1)
        self.num_classes = num_classes
        self.anchor_t = anchor_t
        self.balance = list(balance)
        self.box_gain = box * 3 / num_levels
        self.cls_gain = cls * num_classes / 80 * 3 / num_levels
        self.obj_gain = obj * (image_size / 640) ** 2 * 3 / num_levels
        self.bce = nn.BCEWithLogitsLoss()

    def __call__(
        self, raw: Sequence[torch.Tensor], targets: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(total loss for backward, detached [box, obj, cls] components per image)."""
        device = targets.device
        lbox = torch.zeros((), device=device)
        lobj = torch.zeros((), device=device)
        lcls = torch.zeros((), device=device)
        for level, (p, assigned) in enumerate(zip(raw, self.assign(raw, targets), strict=True)):
            b, a, gj, gi, tbox, anchor, tcls = assigned
            tobj = torch.zeros(p.shape[:4], dtype=p.dtype, device=device)
            if b.numel():
                ps = p[b, a, gj, gi]
                pxy = ps[:, :2].sigmoid() * 2 - 0.5
                pwh = (ps[:, 2:4].sigmoid() * 2) ** 2 * anchor
                iou = ciou(torch.cat((pxy, pwh), dim=1), tbox)
                lbox = lbox + (1 - iou).mean()
                score = (1 - self.iou_ratio) + self.iou_ratio * iou.detach().clamp(min=0)
                tobj[b, a, gj, gi] = score.to(tobj.dtype)
                if self.num_classes > 1:
                    onehot = torch.zeros_like(ps[:, 5:])
                    onehot[torch.arange(len(tcls), device=device), tcls] = 1.0
                    lcls = lcls + self.bce(ps[:, 5:], onehot)
            lobj = lobj + self.bce(p[..., 4], tobj) * self.balance[level]
        lbox, lobj, lcls = lbox * self.box_gain, lobj * self.obj_gain, lcls * self.cls_gain
        batch_size = raw[0].shape[0]
        return (lbox + lobj + lcls) * batch_size, torch.stack((lbox, lobj, lcls)).detach()

    def assign(self, raw: Sequence[torch.Tensor], targets: torch.Tensor) -> list[tuple[torch.Tensor, ...]]:
        """Per level: (image, anchor, grid_y, grid_x, box, anchor_wh, class) of every positive sample.

        A target goes to every anchor whose width and height ratios to it are all below `anchor_t`,
        in its own cell and in the two neighbouring cells nearest to its centre. `box` is the centre
        offset from the cell corner and the size, both in grid units.
        """
        device = targets.device
        num_anchors = self.anchors.shape[1]
        anchor_index = torch.arange(num_anchors, device=device, dtype=targets.dtype)
        # (anchors, M, 7): each target once per anchor, with the anchor index appended.
        tiled = torch.cat(
            (
                targets.unsqueeze(0).expand(num_anchors, -1, -1),
                anchor_index.view(-1, 1, 1).expand(-1, len(targets), 1),
            ),
            dim=2,
        )
        offsets_all = _NEIGHBOUR_OFFSETS.to(device) * 0.5
        out = []
        for level, p in enumerate(raw):
            ny, nx = p.shape[2:4]
            anchors = self.anchors[level].to(device)
            scale = torch.tensor([1, 1, nx, ny, nx, ny, 1], device=device, dtype=targets.dtype)
            t = tiled * scale
            ratio = t[..., 4:6] / anchors.unsqueeze(1)
            t = t[torch.max(ratio, 1 / ratio).amax(dim=2) < self.anchor_t]
            gxy = t[:, 2:4]
            gxy_inverse = torch.tensor([nx, ny], device=device, dtype=t.dtype) - gxy
            left_up = ((gxy % 1 < 0.5) & (gxy > 1)).T
            right_down = ((gxy_inverse % 1 < 0.5) & (gxy_inverse > 1)).T
            use = torch.stack((torch.ones_like(left_up[0]), *left_up, *right_down))
            t = t.unsqueeze(0).expand(5, -1, -1)[use]
            offsets = offsets_all.unsqueeze(1).expand(-1, len(gxy), -1)[use]
            gxy = t[:, 2:4]
            cell = (gxy - offsets).long()
            gi = cell[:, 0].clamp(0, nx - 1)
            gj = cell[:, 1].clamp(0, ny - 1)
            a = t[:, 6].long()
            tbox = torch.cat((gxy - torch.stack((gi, gj), dim=1), t[:, 4:6]), dim=1)
            out.append((t[:, 0].long(), a, gj, gi, tbox, anchors[a], t[:, 1].long()))
        return out
