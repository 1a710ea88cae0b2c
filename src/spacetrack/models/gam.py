"""Global Attention Module (GAM): channel attention then spatial attention, eqs. (20)-(21) of the paper.

F2 = Mc(F1) * F1 and F3 = Ms(F2) * F2, both element-wise with a sigmoid gate. The channel attention
(Fig. 12) permutes the (B, C, H, W) tensor to (B, H, W, C) so that a two-layer perceptron with
reduction `reduction` mixes channels at every pixel without pooling away the spatial layout. The
spatial attention (Fig. 13) is two 7x7 convolutions with batch norm; `groups` > 1 gives the lighter
grouped variant (about `groups` times fewer parameters in the 7x7 convolutions), with a channel
shuffle between them so that groups still exchange information.
"""

from __future__ import annotations

import torch
from torch import nn


def channel_shuffle(x: torch.Tensor, groups: int) -> torch.Tensor:
    """Interleave the channels of `groups` equal groups (B, C, H, W) -> (B, C, H, W)."""
    b, c, h, w = x.shape
    return x.view(b, groups, c // groups, h, w).transpose(1, 2).reshape(b, c, h, w)


class ChannelAttention(nn.Module):
    """Mc: per-pixel channel MLP C -> C/reduction -> C on the permuted tensor, sigmoid gate."""

    def __init__(self, *, channels: int, reduction: int = 4) -> None:
        super().__init__()
        hidden = channels // reduction
        self.mlp = nn.Sequential(
            nn.Linear(channels, hidden), nn.ReLU(inplace=True), nn.Linear(hidden, channels)
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        gate = self.mlp(x.permute(0, 2, 3, 1)).permute(0, 3, 1, 2)
        return x * gate.sigmoid()


class SpatialAttention(nn.Module):
    """Ms: 7x7 conv C -> C/reduction, BN, ReLU, 7x7 conv -> C, BN, sigmoid gate."""

    def __init__(self, *, channels: int, reduction: int = 4, groups: int = 1) -> None:
        super().__init__()
        hidden = channels // reduction
        if channels % groups or hidden % groups:
            raise ValueError(f"GAM groups={groups} must divide channels {channels} and {hidden}")
        self.groups = groups
        self.conv1 = nn.Conv2d(channels, hidden, 7, padding=3, groups=groups)
        self.bn1 = nn.BatchNorm2d(hidden)
        self.act = nn.ReLU(inplace=True)
        self.conv2 = nn.Conv2d(hidden, channels, 7, padding=3, groups=groups)
        self.bn2 = nn.BatchNorm2d(channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.act(self.bn1(self.conv1(x)))
        if self.groups > 1:
            y = channel_shuffle(y, self.groups)
        return x * self.bn2(self.conv2(y)).sigmoid()


class GAM(nn.Module):
    """Global Attention Module; input and output are (B, channels, H, W)."""

    def __init__(self, *, channels: int, reduction: int = 4, groups: int = 1) -> None:
        super().__init__()
        self.channel = ChannelAttention(channels=channels, reduction=reduction)
        self.spatial = SpatialAttention(channels=channels, reduction=reduction, groups=groups)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.spatial(self.channel(x))
