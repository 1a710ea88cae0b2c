"""Detector checkpoints: written atomically, with the architecture and training settings that made them.

A checkpoint is a dict with `arch` (the YOLOv5 constructor keywords), `model` and `ema` state dicts,
`ema_updates`, `optimizer`, `scaler`, `epoch` (last finished, 0-based), `planned_epochs` (the epochs the
run trains in all: fewer than its `epochs` setting where a time budget bound; absent: that setting),
`elapsed_s` (seconds of the time budget spent; absent: none), `partial` (None, or how far the
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


# Settings that may differ on resume: samples are augmented by (seed, epoch, index), not by worker; the
# memory layout of the activations changes the speed, not what is learned (only the order of sums); a
# resumed run plans its remaining epochs with the time budget it is given now.
RESULT_NEUTRAL = ("workers", "progress", "checkpoint_minutes", "channels_last", "max_minutes")
# Settings newer than some checkpoints (trainer keywords and run settings), with the value those
# checkpoints were trained with.
LATER_SETTINGS = {"sync_bn": False, "freeze": 0}


def checkpoint_settings(state: dict[str, Any]) -> dict[str, Any]:
    """The settings a checkpoint was trained with, `LATER_SETTINGS` filled in for older checkpoints."""
    return {**LATER_SETTINGS, **state["settings"]}


def settings_differences(state: dict[str, Any], settings: dict[str, Any]) -> str:
    """`differences` between a checkpoint's settings and a training's, `RESULT_NEUTRAL` aside; a setting
    of `LATER_SETTINGS` that either side lacks counts as its earlier value."""
    return differences(checkpoint_settings(state), {**LATER_SETTINGS, **settings}, ignore=RESULT_NEUTRAL)


def unfinished_checkpoint(
    folders: list[str | Path], *, arch: dict[str, Any], settings: dict[str, Any]
) -> Path | None:
    """The newest `weights/last.pt` under `folders` that a training with `arch` and `settings` (the
    trainer's keywords and the run settings) can resume: same architecture and settings, epochs of its
    plan left (a run that a time budget ended early is finished).
    Files that are not checkpoints are passed over."""
    found = [p for folder in folders for p in Path(folder).glob("**/weights/last.pt")]
    for path in sorted(found, key=lambda p: p.stat().st_mtime, reverse=True):
        try:
            state = peek_checkpoint(path)
        except Exception:
            continue
        if not isinstance(state, dict) or not {"arch", "settings", "epoch"} <= set(state):
            continue
        if differences(state["arch"], arch) or settings_differences(state, settings):
            continue
        if state["epoch"] + 1 < state.get("planned_epochs", settings["epochs"]):
            return path
    return None


def resume_choice(value: object) -> str | Path | None:
    """`resume` of a training config, the same for both networks: null (start afresh), `auto` (the
    training's own unfinished checkpoint, when there is one) or the path of a last.pt, which must exist."""
    if value is None or value == "auto":
        return value
    if not isinstance(value, (str, Path)) or isinstance(value, bool):
        raise ValueError(f"resume must be null, auto or the path of a last.pt, got {value!r}")
    if not Path(value).is_file():
        raise FileNotFoundError(f"resume={value}: no such checkpoint")
    return Path(value)
