"""The re-ID training loop: cosine-softmax identity classification, AdamW, linear warm-up then cosine decay.

It knows the network only as a module that maps crops to unit features and the head as one that maps
features to logits. After every epoch it can hand out its whole state (weights, optimiser, the loader's
and torch's random generators), and started from such a state it trains on exactly as if never stopped.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

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
    autocast: torch.dtype | None = None,
    on_epoch: Callable[[int, dict[str, float]], None] | None = None,
    save_state: Callable[[dict[str, Any]], None] | None = None,
    resume_state: dict[str, Any] | None = None,
) -> dict[str, float]:
    """Train `net` and `head` for `epochs` over `loader` ((crops, identities) batches); returns the last
    epoch's mean loss, accuracy, learning rate and softmax scale, also passed to `on_epoch(epoch, stats)`.

    After each epoch `save_state(state)` gets everything needed to go on; `resume_state` (such a state)
    continues after its epoch. The loader must draw its order from its own `generator`. `autocast`:
    the mixed-precision type of the forward pass (see `engine.trainer.autocast_dtype`; None: float32).
    """
    net.to(device).train()
    head.to(device).train()
    params = list(net.parameters()) + list(head.parameters())
    optimizer = torch.optim.AdamW(params, lr=lr, weight_decay=weight_decay)
    scaler = torch.amp.GradScaler("cuda", enabled=autocast is torch.float16)
    total, warmup = epochs * len(loader), round(warmup_epochs * len(loader))
    if (save_state is not None or resume_state is not None) and loader.generator is None:
        raise ValueError("a resumable re-ID training needs a DataLoader with its own generator")
    start, stats = 0, {}
    if resume_state is not None:
        _restore(resume_state, net, head, optimizer, loader, device)
        start, stats = resume_state["epoch"] + 1, dict(resume_state["stats"])
    step = start * len(loader)
    for epoch in range(start, epochs):
        if hasattr(loader.dataset, "epoch"):
            loader.dataset.epoch = epoch
        loss_sum, correct, seen = 0.0, 0, 0
        for crops, labels in loader:
            crops, labels = crops.to(device), labels.to(device)
            for group in optimizer.param_groups:
                group["lr"] = lr_at(step, total=total, warmup=warmup, lr=lr)
            with torch.autocast(device.type, dtype=autocast, enabled=autocast is not None):
                logits = head(net(crops)).float()
            loss = F.cross_entropy(logits, labels)
            optimizer.zero_grad(set_to_none=True)
            scaler.scale(loss).backward()
            scaler.step(optimizer)
            scaler.update()
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
        if save_state is not None:
            save_state(_state(epoch, stats, net, head, optimizer, loader, device))
    net.eval()
    head.eval()
    return stats


def _state(
    epoch: int,
    stats: dict[str, float],
    net: nn.Module,
    head: nn.Module,
    optimizer: torch.optim.Optimizer,
    loader: DataLoader,
    device: torch.device,
) -> dict[str, Any]:
    """Everything a training needs to go on after `epoch` as if never stopped (see `_restore`)."""
    return {
        "epoch": epoch,
        "net": net.state_dict(),
        "head": head.state_dict(),
        "optimizer": optimizer.state_dict(),
        "loader_rng": loader.generator.get_state(),
        "torch_rng": torch.get_rng_state(),
        "cuda_rng": torch.cuda.get_rng_state(device) if device.type == "cuda" else None,
        "stats": stats,
    }


def _restore(
    state: dict[str, Any],
    net: nn.Module,
    head: nn.Module,
    optimizer: torch.optim.Optimizer,
    loader: DataLoader,
    device: torch.device,
) -> None:
    """Load a `_state` into the training's parts and random generators."""
    net.load_state_dict(state["net"])
    head.load_state_dict(state["head"])
    optimizer.load_state_dict(state["optimizer"])
    loader.generator.set_state(state["loader_rng"])
    torch.set_rng_state(state["torch_rng"])
    if device.type == "cuda" and state.get("cuda_rng") is not None:
        torch.cuda.set_rng_state(state["cuda_rng"], device)
