"""The re-ID training loop: cosine-softmax identity classification, AdamW, linear warm-up then cosine decay.

It knows the network only as a module that maps crops to unit features and the head as one that maps
features to logits.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.data import DataLoader


def lr_at(step: int, *, total: int, warmup: int, lr: float) -> float:
    """Learning rate at optimiser step `step`: linear warm-up over `warmup` steps, then cosine to 0 at `total`."""
    if step < warmup:
        return lr * (step + 1) / warmup
    progress = (step - warmup) / max(1, total - warmup)
    return lr * 0.5 * (1.0 + math.cos(math.pi * min(1.0, progress)))


def fit(
    net: nn.Module,
    head: nn.Module,
    loader: DataLoader,
    *,
    epochs: int,
    lr: float,
    weight_decay: float,
    warmup_epochs: float,
    device: torch.device,
    on_epoch: Callable[[int, dict[str, float]], None] | None = None,
) -> dict[str, float]:
    """Train `net` and `head` for `epochs` over `loader` ((crops, identities) batches); returns the last
    epoch's mean loss, accuracy, learning rate and softmax scale, also passed to `on_epoch(epoch, stats)`."""
    net.to(device).train()
    head.to(device).train()
    params = list(net.parameters()) + list(head.parameters())
    optimizer = torch.optim.AdamW(params, lr=lr, weight_decay=weight_decay)
    total, warmup = epochs * len(loader), round(warmup_epochs * len(loader))
    step, stats = 0, {}
    for epoch in range(epochs):
        if hasattr(loader.dataset, "epoch"):
            loader.dataset.epoch = epoch
        loss_sum, correct, seen = 0.0, 0, 0
        for crops, labels in loader:
            crops, labels = crops.to(device), labels.to(device)
            for group in optimizer.param_groups:
                group["lr"] = lr_at(step, total=total, warmup=warmup, lr=lr)
            logits = head(net(crops))
            loss = F.cross_entropy(logits, labels)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            step += 1
            loss_sum += loss.item() * len(labels)
            correct += int((logits.argmax(1) == labels).sum())
            seen += len(labels)
        stats = {
            "train_loss": loss_sum / seen,
            "train_accuracy": correct / seen,
            "lr": optimizer.param_groups[0]["lr"],
            "softmax_scale": float(getattr(head, "scale", torch.tensor(float("nan"))).detach()),
        }
        if on_epoch is not None:
            on_epoch(epoch, stats)
    net.eval()
    head.eval()
    return stats
