"""Detector checkpoints: written atomically, with the architecture and training settings that made them.

A checkpoint is a dict with `arch` (the YOLOv5 constructor keywords), `model` and `ema` state dicts,
`ema_updates`, `optimizer`, `scaler`, `epoch` (last finished, 0-based), `partial` (None, or how far the
next epoch got when the checkpoint was written mid-epoch: `batch`, counted in global batches, and the
loss sums so far of all processes), `best_fitness`, `history` (metrics per epoch), `settings` (the
trainer's keywords) and `world_size` (the processes that trained it; absent: one). Loading one for
another architecture, or resuming with other settings, is an error that names what differs; another
number of processes is allowed (see `engine.trainer`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from spacetrack.io import atomic_path, load_torch_file
from spacetrack.models.yolo import YOLOv5


def save_checkpoint(path: str | Path, state: dict[str, Any]) -> None:
    """Write `state` to `path`; a crash mid-write leaves the previous file intact."""
    with atomic_path(path) as tmp:
        torch.save(state, tmp)


def differences(found: dict[str, Any], expected: dict[str, Any], ignore: tuple[str, ...] = ()) -> str:
    """'key: checkpoint X, configured Y' for every key whose values differ ('' when none do)."""
    keys = sorted((set(found) | set(expected)) - set(ignore))
    return "; ".join(
        f"{k}: checkpoint {found.get(k)!r}, configured {expected.get(k)!r}"
        for k in keys
        if found.get(k) != expected.get(k)
    )


def peek_checkpoint(path: str | Path) -> dict[str, Any]:
    """A checkpoint's entries without reading its tensors (memory-mapped: only what is touched is read),
    for looking at its settings, epoch or run id; the same errors as `load_checkpoint` for a missing or
    unreadable file."""
    return load_torch_file(path, "checkpoint", mmap=True)


def load_checkpoint(path: str | Path, *, arch: dict[str, Any] | None = None) -> dict[str, Any]:
    """Read a checkpoint (on the CPU); with `arch`, refuse one made for a different architecture."""
    state = load_torch_file(path, "checkpoint")
    if not isinstance(state, dict) or "arch" not in state or "ema" not in state:
        raise ValueError(f"{path} is not a spacetrack detector checkpoint (no 'arch' and 'ema' entries)")
    if arch is not None and differences(state["arch"], arch):
        raise ValueError(f"{path} was trained for another architecture: {differences(state['arch'], arch)}")
    return state


def load_detector(path: str | Path) -> YOLOv5:
    """The EMA weights of a checkpoint in a model built from its own `arch`, in eval mode."""
    state = load_checkpoint(path)
    model = YOLOv5(**state["arch"])
    model.load_state_dict(state["ema"])
    return model.eval()
