"""The loop's schedule, the cosine-softmax head, and a fit on a toy problem (no image network needed)."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.data import DataLoader, TensorDataset

from spacetrack.reid.loss import CosineSoftmax
from spacetrack.reid.train import fit, lr_at


def test_learning_rate_warms_up_then_decays_to_zero() -> None:
    assert lr_at(0, total=100, warmup=10, lr=1.0) == pytest.approx(0.1)
    assert lr_at(9, total=100, warmup=10, lr=1.0) == pytest.approx(1.0)
    assert lr_at(55, total=100, warmup=10, lr=1.0) == pytest.approx(0.5)
    assert lr_at(100, total=100, warmup=10, lr=1.0) == pytest.approx(0.0)


def test_cosine_softmax_logits_are_scaled_cosines() -> None:
    head = CosineSoftmax(feature_dim=2, num_classes=2, init_scale=5.0)
    with torch.no_grad():
        head.weight.copy_(torch.tensor([[3.0, 0.0], [0.0, -2.0]]))
    feature = torch.tensor([[math.cos(0.3), math.sin(0.3)]])
    torch.testing.assert_close(head(feature), 5.0 * torch.tensor([[math.cos(0.3), -math.sin(0.3)]]))
    with pytest.raises(ValueError, match="at least 2 identities"):
        CosineSoftmax(feature_dim=2, num_classes=1)


class Toy(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.linear = nn.Linear(4, 3)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.normalize(self.linear(x), dim=1)


def toy_fit(seed: int) -> tuple[dict[str, float], torch.Tensor]:
    torch.manual_seed(seed)
    labels = torch.arange(60) % 3
    x = F.one_hot(labels, 4).float() + 0.1 * torch.randn(60, 4)
    loader = DataLoader(
        TensorDataset(x, labels), batch_size=12, shuffle=True, generator=torch.Generator().manual_seed(0)
    )
    net, head = Toy(), CosineSoftmax(feature_dim=3, num_classes=3)
    epochs = []
    stats = fit(
        net,
        head,
        loader,
        epochs=15,
        lr=0.05,
        weight_decay=0.0,
        warmup_epochs=1,
        device=torch.device("cpu"),
        on_epoch=lambda e, s: epochs.append((e, s["train_loss"])),
    )
    assert [e for e, _ in epochs] == list(range(15))
    assert epochs[-1][1] < epochs[0][1]
    return stats, net.linear.weight.detach().clone()


def test_fit_learns_a_toy_problem_deterministically() -> None:
    stats, weight = toy_fit(0)
    assert stats["train_accuracy"] == 1.0
    again, weight_again = toy_fit(0)
    assert again == stats
    torch.testing.assert_close(weight_again, weight, rtol=0, atol=0)
