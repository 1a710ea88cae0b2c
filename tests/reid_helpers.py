"""The toy re-ID problem the training tests share: 60 noisy one-hot points of 3 identities, and a
linear network onto the unit sphere."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


class Toy(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.linear = nn.Linear(4, 3)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.normalize(self.linear(x), dim=1)


def toy_points(generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """(60, 4) points and their (60,) labels 0..2: one-hot plus noise of 0.1 (from `generator`)."""
    labels = torch.arange(60) % 3
    return F.one_hot(labels, 4).float() + 0.1 * torch.randn(60, 4, generator=generator), labels
