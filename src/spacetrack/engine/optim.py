"""The YOLOv5 optimisation recipe: SGD Nesterov with three parameter groups, warm-up, linear or cosine
learning-rate decay, and an exponential moving average (EMA) of the weights."""

from __future__ import annotations

import copy
import math

import numpy as np
import torch
from torch import nn

SCHEDULES = ("linear", "cosine")


def build_optimizer(model: nn.Module, *, lr0: float, momentum: float, weight_decay: float) -> torch.optim.SGD:
    """SGD Nesterov; groups: 0 = BN weights (no decay), 1 = other weights (decay), 2 = biases (no decay)."""
    bn_weights, weights, biases = [], [], []
    for module in model.modules():
        if isinstance(getattr(module, "bias", None), nn.Parameter):
            biases.append(module.bias)
        if isinstance(module, nn.modules.batchnorm._BatchNorm):
            bn_weights.append(module.weight)
        elif isinstance(getattr(module, "weight", None), nn.Parameter):
            weights.append(module.weight)
    groups = [
        {"params": bn_weights, "weight_decay": 0.0},
        {"params": weights, "weight_decay": weight_decay},
        {"params": biases, "weight_decay": 0.0},
    ]
    return torch.optim.SGD(groups, lr=lr0, momentum=momentum, nesterov=True)


def lr_factor(epoch: float, *, epochs: int, lrf: float, schedule: str) -> float:
    """Multiplier of the initial learning rate at `epoch`: 1 at the start, `lrf` at the end."""
    if schedule == "linear":
        return (1 - epoch / epochs) * (1.0 - lrf) + lrf
    if schedule == "cosine":
        return ((1 - math.cos(epoch * math.pi / epochs)) / 2) * (lrf - 1) + 1
    raise ValueError(f"schedule {schedule!r} is not one of {SCHEDULES}")


def set_learning_rates(
    optimizer: torch.optim.SGD,
    *,
    iteration: int,
    warmup_iterations: int,
    target_lr: float,
    momentum: float,
    warmup_momentum: float,
    warmup_bias_lr: float,
) -> None:
    """Set every group's rate and momentum for `iteration` (0-based, counted over the whole run).

    During warm-up the biases' rate ramps down from `warmup_bias_lr` and the others' up from 0, and
    the momentum up from `warmup_momentum`; afterwards every group uses `target_lr` and `momentum`.
    """
    for index, group in enumerate(optimizer.param_groups):
        if iteration >= warmup_iterations:
            group["lr"], group["momentum"] = target_lr, momentum
            continue
        x = [0, warmup_iterations]
        start = warmup_bias_lr if index == 2 else 0.0
        group["lr"] = float(np.interp(iteration, x, [start, target_lr]))
        group["momentum"] = float(np.interp(iteration, x, [warmup_momentum, momentum]))


class ModelEMA:
    """Moving average of a model's weights and BN statistics; the decay ramps up over `tau` updates."""

    def __init__(
        self, model: nn.Module, *, decay: float = 0.9999, tau: float = 2000.0, updates: int = 0
    ) -> None:
        self.module = copy.deepcopy(model).eval()
        self.decay = decay
        self.tau = tau
        self.updates = updates
        # weights the model does not train (frozen blocks): the copy holds them already, and averaging
        # them would only round them
        self.fixed = {name for name, p in model.named_parameters() if not p.requires_grad}
        for p in self.module.parameters():
            p.requires_grad_(False)

    @torch.no_grad()
    def update(self, model: nn.Module) -> None:
        self.updates += 1
        d = self.decay * (1 - math.exp(-self.updates / self.tau))
        source = model.state_dict()
        for name, value in self.module.state_dict().items():
            if name not in self.fixed and value.dtype.is_floating_point:
                value.mul_(d).add_(source[name].detach(), alpha=1 - d)
