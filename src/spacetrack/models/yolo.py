"""YOLOv5 (v6/v7 layout: 6x6 stem, C3 blocks, SPPF, PAN neck, three-level anchor head) with optional GAM.

Depth 0.33 and width 0.50 give YOLOv5s: 7,235,389 parameters at 80 classes, 7,022,326 at one class.
`p2=True` adds a fourth detection level at stride 4 (the backbone's stride-4 features joined with the
stride-8 neck output, as YOLOv5's P2 models do) for targets of a few pixels. The stride-8 to stride-32
path is left as it is and the new level comes last in the head, so a three-level file loads into the
first three (`spacetrack.engine.pretrained`) and the new level starts from its initialisation.
`forward` returns the raw head outputs the loss needs; `predict` decodes them into boxes.

Box format of `predict`: (B, N, 5 + num_classes) rows `cx, cy, w, h, objectness, class scores...` in
input-image pixels (xywh centre form), scores after the sigmoid.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence

import torch
from torch import nn

from spacetrack.models.common import C3, SPPF, Conv
from spacetrack.models.gam import GAM, SpatialAttention

# Anchor (w, h) pairs in pixels for strides 8, 16 and 32, fitted by the reference project on COCO.
COCO_ANCHORS = ((10, 13, 16, 30, 33, 23), (30, 61, 62, 45, 59, 119), (116, 90, 156, 198, 373, 326))
# Anchors of the optional stride-4 level: the stride-8 ones halved.
P2_ANCHORS = (5, 6.5, 8, 15, 16.5, 11.5)
GAM_POSITIONS = (None, "before_sppf", "after_sppf")


def scaled_channels(channels: int, width_multiple: float) -> int:
    """Channels times the width multiple, rounded up to a multiple of 8."""
    return int(math.ceil(channels * width_multiple / 8) * 8)


def scaled_depth(n: int, depth_multiple: float) -> int:
    """Number of Bottlenecks in a C3 after the depth multiple (at least one)."""
    return max(round(n * depth_multiple), 1)


class Detect(nn.Module):
    """Per level a 1x1 conv to anchors x (5 + classes); decodes with the v5 sigmoid box parametrisation."""

    def __init__(
        self, *, num_classes: int, anchors: Sequence[Sequence[float]], channels: Sequence[int]
    ) -> None:
        super().__init__()
        self.num_classes = num_classes
        self.num_outputs = num_classes + 5
        self.num_levels = len(anchors)
        self.num_anchors = len(anchors[0]) // 2
        self.register_buffer(
            "anchors", torch.tensor(anchors, dtype=torch.float32).view(self.num_levels, -1, 2)
        )
        self.register_buffer("stride", torch.ones(self.num_levels))
        self.m = nn.ModuleList(nn.Conv2d(c, self.num_outputs * self.num_anchors, 1) for c in channels)

    def init_biases(self, image_size: int = 640) -> None:
        """Prior on objectness (about 8 objects per 640 image) and classes, so early training is stable."""
        for conv, s in zip(self.m, self.stride.tolist(), strict=True):
            b = conv.bias.detach().view(self.num_anchors, -1)
            b[:, 4] += math.log(8 / (image_size / s) ** 2)
            b[:, 5:] += math.log(0.6 / (self.num_classes - 0.99))
            conv.bias.data = b.view(-1)

    def forward(self, features: Sequence[torch.Tensor]) -> list[torch.Tensor]:
        """Raw outputs, one (B, anchors, ny, nx, 5 + classes) tensor per level (logits)."""
        out = []
        for conv, x in zip(self.m, features, strict=True):
            b, _, ny, nx = x.shape
            out.append(conv(x).view(b, self.num_anchors, self.num_outputs, ny, nx).permute(0, 1, 3, 4, 2))
        return out

    def decode(self, raw: Sequence[torch.Tensor]) -> torch.Tensor:
        """(B, N, 5 + classes): cx, cy, w, h in pixels, then sigmoid objectness and class scores, in float32
        whatever precision the network ran in (a bfloat16 pixel coordinate near 500 is only good to 2 px)."""
        out = []
        for i, p in enumerate(raw):
            p = p.float()
            b, na, ny, nx, no = p.shape
            yv, xv = torch.meshgrid(
                torch.arange(ny, device=p.device, dtype=p.dtype),
                torch.arange(nx, device=p.device, dtype=p.dtype),
                indexing="ij",
            )
            grid = torch.stack((xv, yv), dim=-1).view(1, 1, ny, nx, 2)
            anchor = self.anchors[i].to(p.dtype).view(1, na, 1, 1, 2)
            y = p.sigmoid()
            xy = (y[..., :2] * 2 - 0.5 + grid) * self.stride[i]
            wh = (y[..., 2:4] * 2) ** 2 * anchor
            out.append(torch.cat((xy, wh, y[..., 4:]), dim=-1).view(b, -1, no))
        return torch.cat(out, dim=1)


BACKBONE = ("stem", "stage2", "stage3", "stage4", "stage5")  # the backbone's blocks, input first


class YOLOv5(nn.Module):
    """YOLOv5 backbone (CSP-Darknet with SPPF), PAN neck and Detect head; GAM inserted where configured.

    Input: (B, 3, H, W) RGB floats in [0, 1] with H and W multiples of 32.
    """

    def __init__(
        self,
        *,
        num_classes: int,
        depth_multiple: float = 0.33,
        width_multiple: float = 0.50,
        anchors: Sequence[Sequence[float]] | None = None,
        gam_position: str | None = None,
        gam_reduction: int = 4,
        gam_groups: int = 1,
        p2: bool = False,
    ) -> None:
        super().__init__()
        if gam_position not in GAM_POSITIONS:
            raise ValueError(f"gam_position {gam_position!r} is not one of {GAM_POSITIONS}")
        if num_classes < 1:
            raise ValueError(f"num_classes must be at least 1, got {num_classes}")
        if anchors is None:
            anchors = (*COCO_ANCHORS, P2_ANCHORS) if p2 else COCO_ANCHORS
        if len(anchors) != 3 + bool(p2):
            raise ValueError(f"{len(anchors)} anchor levels for a {3 + bool(p2)}-level head (p2={p2})")
        # Everything needed to rebuild the network; checkpoints store it and refuse a mismatch.
        self.arch = {
            "num_classes": int(num_classes),
            "depth_multiple": float(depth_multiple),
            "width_multiple": float(width_multiple),
            "anchors": [list(map(float, a)) for a in anchors],
            "gam_position": gam_position,
            "gam_reduction": int(gam_reduction),
            "gam_groups": int(gam_groups),
        }
        if p2:  # only then, so the three-level network's files keep the arch they were written with
            self.arch["p2"] = True
        c = [scaled_channels(x, width_multiple) for x in (64, 128, 256, 512, 1024)]
        n = [scaled_depth(x, depth_multiple) for x in (3, 6, 9)]

        def gam() -> nn.Module:
            return GAM(channels=c[4], reduction=gam_reduction, groups=gam_groups)

        self.stem = Conv(3, c[0], 6, 2, 2)
        self.stage2 = nn.Sequential(Conv(c[0], c[1], 3, 2), C3(c[1], c[1], n[0]))
        self.stage3 = nn.Sequential(Conv(c[1], c[2], 3, 2), C3(c[2], c[2], n[1]))  # P3, stride 8
        self.stage4 = nn.Sequential(Conv(c[2], c[3], 3, 2), C3(c[3], c[3], n[2]))  # P4, stride 16
        self.stage5 = nn.Sequential(
            Conv(c[3], c[4], 3, 2),
            C3(c[4], c[4], n[0]),
            gam() if gam_position == "before_sppf" else nn.Identity(),
            SPPF(c[4], c[4], 5),
            gam() if gam_position == "after_sppf" else nn.Identity(),
        )  # P5, stride 32

        self.lateral5 = Conv(c[4], c[3], 1, 1)
        self.up = nn.Upsample(scale_factor=2, mode="nearest")
        self.top_down4 = C3(c[4], c[3], n[0], shortcut=False)
        self.lateral4 = Conv(c[3], c[2], 1, 1)
        self.top_down3 = C3(c[3], c[2], n[0], shortcut=False)
        self.down3 = Conv(c[2], c[2], 3, 2)
        self.bottom_up4 = C3(c[3], c[3], n[0], shortcut=False)
        self.down4 = Conv(c[3], c[3], 3, 2)
        self.bottom_up5 = C3(c[4], c[4], n[0], shortcut=False)

        head_channels: tuple[int, ...] = (c[2], c[3], c[4])
        if p2:
            self.lateral3 = Conv(c[2], c[1], 1, 1)
            self.top_down2 = C3(c[2], c[1], n[0], shortcut=False)
            head_channels += (c[1],)
        self.detect = Detect(num_classes=num_classes, anchors=anchors, channels=head_channels)
        with torch.no_grad():
            levels = self(torch.zeros(1, 3, 256, 256))
        self.detect.stride.copy_(torch.tensor([256 / p.shape[2] for p in levels]))
        self.detect.init_biases()

    @property
    def stride(self) -> torch.Tensor:
        return self.detect.stride

    def freeze_backbone(self, stages: int) -> list[str]:
        """Stop training the first `stages` blocks of the backbone (`BACKBONE`, 0-5; 5: all of it with
        its GAM, YOLOv5's `--freeze 10`): their weights keep their values and get no gradient, so
        backpropagation stops where they end. Their BatchNorm statistics still follow the data in
        training mode, as in YOLOv5. Returns the names of the frozen blocks."""
        if isinstance(stages, bool) or not isinstance(stages, int) or not 0 <= stages <= len(BACKBONE):
            raise ValueError(
                f"freeze: expected 0-{len(BACKBONE)} backbone stages ({', '.join(BACKBONE)}), got {stages!r}"
            )
        for name in BACKBONE[:stages]:
            for parameter in getattr(self, name).parameters():
                parameter.requires_grad_(False)
        return list(BACKBONE[:stages])

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """Raw head outputs per level (see Detect.forward)."""
        p2 = self.stage2(self.stem(x))
        p3 = self.stage3(p2)
        p4 = self.stage4(p3)
        p5 = self.stage5(p4)
        h5 = self.lateral5(p5)
        h4 = self.lateral4(self.top_down4(torch.cat((self.up(h5), p4), dim=1)))
        out3 = self.top_down3(torch.cat((self.up(h4), p3), dim=1))
        out4 = self.bottom_up4(torch.cat((self.down3(out3), h4), dim=1))
        out5 = self.bottom_up5(torch.cat((self.down4(out4), h5), dim=1))
        if "p2" not in self.arch:
            return self.detect((out3, out4, out5))
        out2 = self.top_down2(torch.cat((self.up(self.lateral3(out3)), p2), dim=1))
        return self.detect((out3, out4, out5, out2))

    def predict(self, x: torch.Tensor) -> torch.Tensor:
        """Decoded predictions (B, N, 5 + classes), see the module docstring."""
        return self.detect.decode(self(x))


def fused_conv(conv: nn.Conv2d, bn: nn.BatchNorm2d) -> nn.Conv2d:
    """One convolution computing `bn(conv(x))` with the batch norm's running statistics (eval mode):
    weight scaled per output channel by gamma / sqrt(var + eps), bias beta - mean * that scale (plus the
    convolution's own bias scaled alike)."""
    fused = nn.Conv2d(
        conv.in_channels,
        conv.out_channels,
        conv.kernel_size,
        conv.stride,
        conv.padding,
        conv.dilation,
        conv.groups,
        bias=True,
        padding_mode=conv.padding_mode,
    ).to(conv.weight.device)
    with torch.no_grad():
        scale = bn.weight / torch.sqrt(bn.running_var + bn.eps)
        bias = conv.bias if conv.bias is not None else torch.zeros_like(bn.running_mean)
        fused.weight.copy_(conv.weight * scale.view(-1, 1, 1, 1))
        fused.bias.copy_(bn.bias + (bias - bn.running_mean) * scale)
    return fused.requires_grad_(False)


def fuse_for_inference(model: YOLOv5) -> YOLOv5:
    """An eval-mode copy of `model` with every Conv-BN pair folded into one convolution (the network's
    `Conv` blocks and GAM's spatial attention): the same outputs up to float rounding, fewer passes over
    memory. The copy is for inference only; `model` itself, its training and its checkpoints are
    untouched."""
    fused = copy.deepcopy(model).eval()
    for module in fused.modules():
        if isinstance(module, Conv) and isinstance(module.bn, nn.BatchNorm2d):
            module.conv, module.bn = fused_conv(module.conv, module.bn), nn.Identity()
        elif isinstance(module, SpatialAttention):
            module.conv1, module.bn1 = fused_conv(module.conv1, module.bn1), nn.Identity()
            module.conv2, module.bn2 = fused_conv(module.conv2, module.bn2), nn.Identity()
    return fused.requires_grad_(False)


def count_parameters(model: nn.Module) -> int:
    """Number of trainable and frozen parameters (buffers such as BN statistics excluded)."""
    return sum(p.numel() for p in model.parameters())
