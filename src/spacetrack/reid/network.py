"""The re-ID CNN of Table 1 (the DeepSORT appearance network): a 3x128x64 crop -> 128-d unit vector.

| layer        | patch / stride | output     |
|--------------|----------------|------------|
| conv 1       | 3x3 / 1        | 32x128x64  |
| conv 2       | 3x3 / 1        | 32x128x64  |
| max pool 3   | 3x3 / 2        | 32x64x32   |
| residual 4-5 | 3x3 / 1        | 32x64x32   |
| residual 6   | 3x3 / 2        | 64x32x16   |
| residual 7   | 3x3 / 1        | 64x32x16   |
| residual 8   | 3x3 / 2        | 128x16x8   |
| residual 9   | 3x3 / 1        | 128x16x8   |
| dense 10     |                | 128        |
| BN + L2 norm |                | 128        |

Batch normalisation and ELU follow every convolution as in the original network; residual blocks are
pre-activation (BN, ELU, conv, BN, ELU, dropout, conv, plus a 1x1 strided projection where the width
doubles). One deliberate difference: the original applies ELU to the dense layer before normalising,
which keeps features near the positive orthant and squeezes every distance between different targets
towards zero; here the dense layer is followed by BN only (`final_elu=True` restores the original).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

BLOCK_WIDTHS = (32, 32, 64, 64, 128, 128)


def conv_bn_elu(c_in: int, c_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_out, 3, padding=1, bias=False), nn.BatchNorm2d(c_out), nn.ELU())


class ResidualBlock(nn.Module):
    """Pre-activation residual block; `downsample` halves the resolution with stride 2 in its first conv."""

    def __init__(self, c_in: int, c_out: int, *, downsample: bool, preactivate: bool, dropout: float) -> None:
        super().__init__()
        stride = 2 if downsample else 1
        # The first block follows conv 2's own BN and ELU (through the pool), so it skips its own.
        self.pre = nn.Sequential(nn.BatchNorm2d(c_in), nn.ELU()) if preactivate else nn.Identity()
        self.conv1 = nn.Conv2d(c_in, c_out, 3, stride=stride, padding=1, bias=False)
        self.mid = nn.Sequential(nn.BatchNorm2d(c_out), nn.ELU(), nn.Dropout(dropout))
        self.conv2 = nn.Conv2d(c_out, c_out, 3, padding=1, bias=False)
        self.shortcut = (
            nn.Conv2d(c_in, c_out, 1, stride=stride, bias=False)
            if downsample or c_in != c_out
            else nn.Identity()
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.shortcut(x) + self.conv2(self.mid(self.conv1(self.pre(x))))


class ReidNet(nn.Module):
    """Table 1 network. Input (N, 3, input_height, input_width) RGB floats in [0, 1]; output (N, feature_dim)
    L2-normalised features, so the cosine distance of two crops is 1 - a.b.

    `input_height`/`input_width` must be multiples of 8 (three halvings); Table 1 uses 128 x 64.
    """

    def __init__(
        self,
        *,
        input_height: int = 128,
        input_width: int = 64,
        feature_dim: int = 128,
        dropout: float = 0.3,
        final_elu: bool = False,
    ) -> None:
        super().__init__()
        if input_height % 8 or input_width % 8 or input_height <= 0 or input_width <= 0:
            raise ValueError(f"input size {input_height}x{input_width} must be positive multiples of 8")
        self.input_height, self.input_width, self.feature_dim = input_height, input_width, feature_dim
        self.stem = nn.Sequential(
            conv_bn_elu(3, 32), conv_bn_elu(32, 32), nn.MaxPool2d(3, stride=2, padding=1)
        )
        blocks, c_in = [], 32
        for i, c_out in enumerate(BLOCK_WIDTHS):
            blocks.append(
                ResidualBlock(c_in, c_out, downsample=c_out != c_in, preactivate=i > 0, dropout=dropout)
            )
            c_in = c_out
        self.blocks = nn.Sequential(*blocks, nn.BatchNorm2d(c_in), nn.ELU())
        flat = c_in * (input_height // 8) * (input_width // 8)
        head = [nn.Flatten(), nn.Dropout(dropout), nn.Linear(flat, feature_dim, bias=False)]
        head.append(nn.BatchNorm1d(feature_dim))
        if final_elu:
            head.append(nn.ELU())
        self.head = nn.Sequential(*head)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.ndim != 4 or x.shape[1:] != (3, self.input_height, self.input_width):
            raise ValueError(
                f"ReidNet expects (N, 3, {self.input_height}, {self.input_width}) crops, got {tuple(x.shape)}"
            )
        return F.normalize(self.head(self.blocks(self.stem(x))), dim=1)
