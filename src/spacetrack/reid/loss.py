"""Cosine-softmax classifier (cosine metric learning, the original DeepSORT re-ID training).

Logits are kappa x cos(angle between feature and class direction): the classes live on the same unit
sphere the tracker measures cosine distances on, so pulling a crop towards its identity's direction is
exactly shrinking the same-target cosine distance, with no pair or triplet mining, which our few
identities per batch would make noisy. kappa = softplus(a learned scalar) sets how sharp the softmax is.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


class CosineSoftmax(nn.Module):
    """Identity classifier over L2-normalised (N, feature_dim) features; `forward` returns (N, num_classes) logits."""

    def __init__(self, *, feature_dim: int, num_classes: int, init_scale: float = 10.0) -> None:
        super().__init__()
        if num_classes < 2:
            raise ValueError(f"cosine softmax needs at least 2 identities, got {num_classes}")
        self.weight = nn.Parameter(torch.randn(num_classes, feature_dim) * 0.01)
        # softplus^-1(init_scale), so training starts at kappa = init_scale
        self.raw_scale = nn.Parameter(torch.tensor(float(init_scale)).expm1().log())

    @property
    def scale(self) -> torch.Tensor:
        return F.softplus(self.raw_scale)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return self.scale * features @ F.normalize(self.weight, dim=1).T
