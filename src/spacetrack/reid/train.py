"""The re-ID training loop: cosine-softmax identity classification, AdamW, linear warm-up then cosine decay.

It knows the network only as a module that maps crops to unit features and the head as one that maps
features to logits. After every epoch it can hand out its whole state (weights, optimiser, the loader's
and torch's random generators), and started from such a state it trains on exactly as if never stopped.
Launched in several processes (torchrun) it trains one network with DistributedDataParallel.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.data import DataLoader, Dataset

from spacetrack.engine.distributed import (
    ShardedRandomSampler,
    check_batch_split,
    current_world,
    distribute_model,
    sum_across,
)


def lr_at(step: int, *, total: int, warmup: int, lr: float) -> float:
    """Learning rate at optimiser step `step`: linear warm-up over `warmup` steps, then cosine to 0 at `total`."""
    if step < warmup:
        return lr * (step + 1) / warmup
    progress = (step - warmup) / max(1, total - warmup)
    return lr * 0.5 * (1.0 + math.cos(math.pi * min(1.0, progress)))


def shuffled_loader(dataset: Dataset, *, batch_size: int, seed: int, workers: int = 0) -> DataLoader:
    """Batches of `dataset` in a new random order each epoch, drawn from the loader's own generator
    (seeded with `seed`, saved with a checkpoint); the last incomplete batch is dropped unless it is the
    only one. Among several processes `batch_size` is the global batch: each process loads its share of
    every batch of the same order (`engine.distributed.ShardedRandomSampler`)."""
    world = current_world()
    generator = torch.Generator().manual_seed(seed)
    if not world.distributed:
        drop_last = len(dataset) >= batch_size
        return DataLoader(dataset, batch_size=batch_size, shuffle=True, drop_last=drop_last,
                          num_workers=workers, generator=generator)  # fmt: skip
    share = check_batch_split(batch_size, world, key="train_reid.batch_size")
    if len(dataset) < batch_size:
        raise ValueError(
            f"train_reid.batch_size={batch_size} is more than the {len(dataset)} training crops: a training "
            "in several processes needs one full batch"
        )
    sampler = ShardedRandomSampler(
        len(dataset), batch_size=batch_size, world=world, generator=generator, drop_last=True
    )
    return DataLoader(dataset, batch_size=share, sampler=sampler, num_workers=workers, generator=generator)


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
    sync_bn: bool = False,
    on_epoch: Callable[[int, dict[str, float]], None] | None = None,
    save_state: Callable[[dict[str, Any]], None] | None = None,
    resume_state: dict[str, Any] | None = None,
) -> dict[str, float]:
    """Train `net` and `head` for `epochs` over `loader` ((crops, identities) batches); returns the last
    epoch's mean loss, accuracy, learning rate and softmax scale, also passed to `on_epoch(epoch, stats)`.

    After each epoch `save_state(state)` gets everything needed to go on; `resume_state` (such a state)
    continues after its epoch. The loader must draw its order from its own `generator`. `autocast`:
    the mixed-precision type of the forward pass (see `engine.precision.autocast_dtype`; None: float32).
    In a distributed training (`shuffled_loader`'s batches, one process per device) the processes train
    together with DistributedDataParallel, BatchNorm synchronised with `sync_bn` (CUDA); the stats are
    those of all processes, and rank 0 alone calls `on_epoch` and `save_state`.
    """
    world = current_world()
    net.to(device).train()
    head.to(device).train()
    model = distribute_model(_Classifier(net, head), device, world, sync_bn=sync_bn)
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
        counts = torch.zeros(3, dtype=torch.float64)  # loss sum, correct, crops
        for crops, labels in loader:
            for group in optimizer.param_groups:
                group["lr"] = lr_at(step, total=total, warmup=warmup, lr=lr)
            counts += _train_step(model, optimizer, scaler, crops.to(device), labels.to(device), autocast)
            step += 1
        stats = _epoch_stats(sum_across(counts, world), optimizer, head)
        if world.is_main and on_epoch is not None:
            on_epoch(epoch, stats)
        if world.is_main and save_state is not None:
            save_state(_state(epoch, stats, net, head, optimizer, loader, device))
    net.eval()
    head.eval()
    return stats


def _train_step(
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    scaler: torch.amp.GradScaler,
    crops: torch.Tensor,
    labels: torch.Tensor,
    autocast: torch.dtype | None,
) -> torch.Tensor:
    """One optimiser step on a batch; returns (loss sum, correct, crops) of the batch as float64."""
    with torch.autocast(crops.device.type, dtype=autocast, enabled=autocast is not None):
        logits = model(crops).float()
    loss = F.cross_entropy(logits, labels)
    optimizer.zero_grad(set_to_none=True)
    scaler.scale(loss).backward()
    scaler.step(optimizer)
    scaler.update()
    correct = int((logits.argmax(1) == labels).sum())
    return torch.tensor([loss.item() * len(labels), correct, len(labels)], dtype=torch.float64)


class _Classifier(nn.Module):
    """The network and its head as one module (what DistributedDataParallel wraps): crops to logits."""

    def __init__(self, net: nn.Module, head: nn.Module) -> None:
        super().__init__()
        self.net, self.head = net, head

    def forward(self, crops: torch.Tensor) -> torch.Tensor:
        return self.head(self.net(crops))


def _epoch_stats(counts: torch.Tensor, optimizer: torch.optim.Optimizer, head: nn.Module) -> dict[str, float]:
    """Mean loss and accuracy of an epoch from its (loss sum, correct, crops), the last learning rate
    and the head's softmax scale."""
    loss_sum, correct, seen = counts.tolist()
    return {
        "train_loss": loss_sum / seen,
        "train_accuracy": correct / seen,
        "lr": optimizer.param_groups[0]["lr"],
        "softmax_scale": float(getattr(head, "scale", torch.tensor(float("nan"))).detach()),
    }


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
