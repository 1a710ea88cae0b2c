"""The loop's schedule, the cosine-softmax head, and a fit on a toy problem (no image network needed)."""

from __future__ import annotations

import copy
import math

import pytest
import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.data import DataLoader, TensorDataset

from reid_helpers import Toy, toy_points
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


def toy_fit(seed: int) -> tuple[dict[str, float], torch.Tensor]:
    torch.manual_seed(seed)
    x, labels = toy_points()
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


class DropoutToy(nn.Module):
    """Dropout draws from torch's global generator, which a resume must restore too."""

    def __init__(self) -> None:
        super().__init__()
        self.linear = nn.Linear(4, 3)
        self.drop = nn.Dropout(0.3)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.normalize(self.linear(self.drop(x)), dim=1)


def dropout_fit(epochs: int, *, resume: dict | None = None) -> tuple[list[dict], nn.Module]:
    torch.manual_seed(0)
    x, labels = toy_points()
    loader = DataLoader(
        TensorDataset(x, labels), batch_size=12, shuffle=True, generator=torch.Generator().manual_seed(0)
    )
    net, head = DropoutToy(), CosineSoftmax(feature_dim=3, num_classes=3)
    states: list[dict] = []
    fit(
        net,
        head,
        loader,
        epochs=epochs,
        lr=0.05,
        weight_decay=0.01,
        warmup_epochs=1,
        device=torch.device("cpu"),
        save_state=lambda s: states.append(copy.deepcopy(s)),
        resume_state=resume,
    )
    return states, net


def test_a_resumed_fit_ends_where_an_unbroken_one_does() -> None:
    states, net = dropout_fit(6)
    assert [s["epoch"] for s in states] == list(range(6))
    after, resumed = dropout_fit(6, resume=states[2])
    assert [s["epoch"] for s in after] == [3, 4, 5]
    torch.testing.assert_close(resumed.linear.weight, net.linear.weight, rtol=0, atol=0)
    assert after[-1]["stats"] == states[-1]["stats"]
    # Without the generators' states the same weights and optimiser give another result.
    broken = {**states[2], "torch_rng": torch.random.default_generator.get_state()}
    _, other = dropout_fit(6, resume=broken)
    assert not torch.equal(other.linear.weight, net.linear.weight)


def test_resuming_needs_a_loader_with_its_own_generator() -> None:
    loader = DataLoader(TensorDataset(torch.zeros(4, 4), torch.zeros(4, dtype=torch.long)), batch_size=2)
    with pytest.raises(ValueError, match="own generator"):
        fit(
            Toy(),
            CosineSoftmax(feature_dim=3, num_classes=2),
            loader,
            epochs=1,
            lr=0.1,
            weight_decay=0.0,
            warmup_epochs=0,
            device=torch.device("cpu"),
            save_state=lambda s: None,
        )
