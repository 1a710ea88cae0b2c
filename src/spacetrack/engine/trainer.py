"""The detector training loop: epochs of SGD with warm-up and EMA, validation, best/last checkpoints.

Everything random in an epoch (sample order, augmentation) is drawn from (seed, epoch), gradients never
cross an epoch boundary and the checkpoint holds the full optimiser, EMA and scaler state, so resuming
from `last.pt` after a kill gives the same weights as a run that was never interrupted.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from torch import nn
from torch.utils.data import DataLoader, Dataset
from tqdm import tqdm

from spacetrack.data.yolo_dataset import collate
from spacetrack.device import resolve_device
from spacetrack.engine.checkpoint import differences, load_checkpoint, peek_checkpoint, save_checkpoint
from spacetrack.engine.optim import ModelEMA, build_optimizer, lr_factor, set_learning_rates
from spacetrack.engine.validate import evaluate

# Settings that may differ on resume: samples are augmented by (seed, epoch, index), not by worker.
RESULT_NEUTRAL = ("workers", "progress", "checkpoint_minutes")
EpochCallback = Callable[[dict[str, float], dict[str, Any], bool], None]


def native_bfloat16() -> bool:
    """Whether this CPU computes bfloat16 natively (AVX-512 BF16 or AMX, as oneDNN reports it); elsewhere
    bfloat16 is emulated and slower than float32."""
    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):
        return False


def autocast_dtype(device: torch.device, amp: bool) -> torch.dtype | None:
    """What mixed precision runs the forward pass in: float16 on CUDA, bfloat16 on a CPU that has it
    natively, None (float32) on other CPUs or with `amp` off."""
    if not amp:
        return None
    if device.type == "cuda":
        return torch.float16
    return torch.bfloat16 if device.type == "cpu" and native_bfloat16() else None


def unfinished_checkpoint(
    folders: list[str | Path], *, arch: dict[str, Any], settings: dict[str, Any]
) -> Path | None:
    """The newest `weights/last.pt` under `folders` that a training with `arch` and `settings` (the
    trainer's keywords and the run settings) can resume: same architecture and settings, epochs left.
    Files that are not checkpoints are passed over."""
    found = [p for folder in folders for p in Path(folder).glob("**/weights/last.pt")]
    for path in sorted(found, key=lambda p: p.stat().st_mtime, reverse=True):
        try:
            state = peek_checkpoint(path)
        except Exception:
            continue
        if not isinstance(state, dict) or not {"arch", "settings", "epoch"} <= set(state):
            continue
        if differences(state["arch"], arch) or differences(
            state["settings"], settings, ignore=RESULT_NEUTRAL
        ):
            continue
        if state["epoch"] + 1 < settings["epochs"]:
            return path
    return None


def fitness(metrics: dict[str, float]) -> float:
    """What `best.pt` maximises: mostly mAP@0.5:0.95, a little mAP@0.5."""
    return 0.1 * metrics["map50"] + 0.9 * metrics["map50_95"]


class Trainer:
    """Keyword arguments are the keys of `train.trainer` in the config; rates are per optimiser step."""

    def __init__(
        self,
        *,
        epochs: int,
        batch_size: int,
        workers: int = 0,
        lr0: float = 0.01,
        lrf: float = 0.01,
        schedule: str = "linear",
        momentum: float = 0.937,
        weight_decay: float = 5e-4,
        nbs: int = 64,
        warmup_epochs: float = 3.0,
        warmup_momentum: float = 0.8,
        warmup_bias_lr: float = 0.1,
        ema_decay: float = 0.9999,
        ema_tau: float = 2000.0,
        grad_clip: float = 10.0,
        amp: bool = True,
        device: str = "auto",
        seed: int = 0,
        conf_threshold: float = 0.001,
        iou_threshold: float = 0.6,
        max_det: int = 300,
        progress: bool = True,
        checkpoint_minutes: float | None = 10.0,
    ) -> None:
        self.settings = {k: v for k, v in locals().items() if k != "self"}
        for key, value in self.settings.items():
            setattr(self, key, value)
        lr_factor(0, epochs=epochs, lrf=lrf, schedule=schedule)  # reject an unknown schedule now

    def fit(
        self,
        *,
        model: nn.Module,
        loss_fn: Callable,
        train_set: Dataset,
        val_set: Dataset,
        out_dir: str | Path,
        resume_from: str | Path | None = None,
        run_settings: dict[str, Any] | None = None,
        on_epoch_end: EpochCallback | None = None,
        extra_state: dict[str, Any] | None = None,
    ) -> dict[str, Any]:
        """Train `model` in place; return `history`, `best_fitness` and the checkpoint paths.

        `run_settings` (data, image size, augmentation...) are stored with the trainer's settings; a
        resume with any of them changed is refused. `extra_state` (the MLflow run id) goes into every
        checkpoint as it is.
        """
        device = resolve_device(self.device)
        model.to(device)
        self.autocast = autocast_dtype(device, self.amp)
        print(f"training on {device} in {self.autocast or torch.float32} (amp={self.amp})", flush=True)
        run = _Run(self, model, {**self.settings, **(run_settings or {})}, extra_state or {}, device)
        if resume_from is not None:
            run.restore(resume_from)
        weights = Path(out_dir) / "weights"
        weights.mkdir(parents=True, exist_ok=True)
        val_loader = DataLoader(
            val_set, batch_size=self.batch_size, num_workers=self.workers, collate_fn=collate
        )
        num_batches = math.ceil(len(train_set) / self.batch_size)
        for epoch in range(run.epoch + 1, self.epochs):
            train_set.set_epoch(epoch)
            components, images_per_s = self._train_epoch(
                run, loss_fn, train_set, epoch, num_batches, last_checkpoint=weights / "last.pt"
            )
            metrics, details = evaluate(
                run.ema.module,
                val_loader,
                device=device,
                conf_threshold=self.conf_threshold,
                iou_threshold=self.iou_threshold,
                max_det=self.max_det,
                loss_fn=loss_fn,
            )
            record = {
                "epoch": epoch,
                **dict(zip(("box", "obj", "cls"), components, strict=True)),
                **metrics,
                "fitness": fitness(metrics),
                "lr": run.optimizer.param_groups[1]["lr"],
                "train_images_per_s": images_per_s,
            }
            is_best = run.finish_epoch(epoch, record)
            save_checkpoint(weights / "last.pt", run.state())
            if is_best:
                save_checkpoint(weights / "best.pt", run.state())
            if on_epoch_end is not None:
                on_epoch_end(record, details, is_best)
        return {
            "history": run.history,
            "best_fitness": run.best,
            "best": weights / "best.pt",
            "last": weights / "last.pt",
        }

    def _train_epoch(
        self,
        run: _Run,
        loss_fn: Callable,
        train_set: Dataset,
        epoch: int,
        num_batches: int,
        last_checkpoint: Path,
    ) -> tuple[list[float], float]:
        """One pass over the epoch's batches, from the first one a mid-epoch checkpoint had not done: mean
        [box, obj, cls] loss per image, and training images per second. Every `checkpoint_minutes` a
        checkpoint is written at the next optimiser step, holding how far the epoch got."""
        model, optimizer, scaler, ema = run.model, run.optimizer, run.scaler, run.ema
        device = next(model.parameters()).device
        target_lr = self.lr0 * lr_factor(epoch, epochs=self.epochs, lrf=self.lrf, schedule=self.schedule)
        order = torch.randperm(
            len(train_set), generator=torch.Generator().manual_seed(self.seed * 100_003 + epoch)
        )
        skip, sums, seen, elapsed = (
            run.partial.pop("batch", 0),
            *run.partial.pop("progress", (torch.zeros(3), 0, 0.0)),
        )
        run.partial.clear()
        loader = DataLoader(train_set, batch_size=self.batch_size, sampler=order.tolist()[skip * self.batch_size :],
                            num_workers=self.workers, collate_fn=collate)  # fmt: skip
        accumulate = run.accumulate
        model.train()
        optimizer.zero_grad()
        started = last_save = time.perf_counter()
        kept_at = f"{epoch} batch {skip}" if skip else (epoch - 1 if epoch else None)
        bar = tqdm(loader, desc=f"epoch {epoch + 1}/{self.epochs}", unit="batch", disable=not self.progress,
                   leave=False, initial=skip, total=num_batches)  # fmt: skip
        for i, (images, targets) in enumerate(bar, start=skip):
            set_learning_rates(
                optimizer,
                iteration=num_batches * epoch + i,
                warmup_iterations=round(self.warmup_epochs * num_batches),
                target_lr=target_lr,
                momentum=self.momentum,
                warmup_momentum=self.warmup_momentum,
                warmup_bias_lr=self.warmup_bias_lr,
            )
            with torch.autocast(device.type, dtype=self.autocast, enabled=self.autocast is not None):
                raw = model(images.to(device).float() / 255)
            loss, components = loss_fn([p.float() for p in raw], targets.to(device))
            if not torch.isfinite(loss):
                kept = (
                    f"{last_checkpoint} (epoch {kept_at}) is kept"
                    if kept_at is not None
                    else "no checkpoint yet"
                )
                raise FloatingPointError(
                    f"training loss is {loss.item()} at epoch {epoch} batch {i}; stopped, {kept}. Lower "
                    "train.trainer.lr0 or check the labels."
                )
            scaler.scale(loss).backward()
            sums += components.cpu() * len(images)
            seen += len(images)
            if (i + 1) % accumulate == 0 or i + 1 == num_batches:
                scaler.unscale_(optimizer)
                nn.utils.clip_grad_norm_(model.parameters(), max_norm=self.grad_clip)
                scaler.step(optimizer)
                scaler.update()
                optimizer.zero_grad()
                ema.update(model)
                now = time.perf_counter()
                due = self.checkpoint_minutes is not None and now - last_save >= 60 * self.checkpoint_minutes
                if due and i + 1 < num_batches:
                    progress = (sums.clone(), seen, elapsed + now - started)
                    save_checkpoint(
                        last_checkpoint, run.state(partial={"batch": i + 1, "progress": progress})
                    )
                    last_save = now
        elapsed += time.perf_counter() - started
        return (sums / max(seen, 1)).tolist(), seen / max(elapsed, 1e-9)


class _Run:
    """What a training carries from step to step and saves: the model, its optimiser, EMA and scaler,
    the last finished epoch, the best fitness, the history, and how far an unfinished epoch got."""

    def __init__(self, trainer: Trainer, model: nn.Module, settings: dict, extra: dict, device: torch.device):
        self.model, self.settings, self.extra = model, settings, extra
        self.accumulate = max(round(trainer.nbs / trainer.batch_size), 1)
        decay = trainer.weight_decay * trainer.batch_size * self.accumulate / trainer.nbs
        self.optimizer = build_optimizer(
            model, lr0=trainer.lr0, momentum=trainer.momentum, weight_decay=decay
        )
        self.ema = ModelEMA(model, decay=trainer.ema_decay, tau=trainer.ema_tau)
        self.scaler = torch.amp.GradScaler("cuda", enabled=trainer.amp and device.type == "cuda")
        self.epoch, self.best, self.history, self.partial = -1, -1.0, [], {}

    def restore(self, path: str | Path) -> None:
        """Continue from the checkpoint at `path`; refuse it when its settings differ."""
        state = load_checkpoint(path, arch=self.model.arch)
        changed = differences(state["settings"], self.settings, ignore=RESULT_NEUTRAL)
        if changed:
            raise ValueError(f"cannot resume {path} with other settings: {changed}")
        self.model.load_state_dict(state["model"])
        self.ema.module.load_state_dict(state["ema"])
        self.ema.updates = state["ema_updates"]
        self.optimizer.load_state_dict(state["optimizer"])
        self.scaler.load_state_dict(state["scaler"])
        self.epoch, self.best, self.history = state["epoch"], state["best_fitness"], state["history"]
        self.partial = dict(state.get("partial") or {})

    def finish_epoch(self, epoch: int, record: dict[str, float]) -> bool:
        """Record a finished epoch; whether it is the best so far."""
        self.epoch = epoch
        self.history.append(record)
        is_best = record["fitness"] > self.best
        self.best = max(self.best, record["fitness"])
        return is_best

    def state(self, partial: dict | None = None) -> dict[str, Any]:
        """The checkpoint: everything `restore` needs (see `engine.checkpoint`)."""
        return {
            "arch": self.model.arch,
            "model": self.model.state_dict(),
            "ema": self.ema.module.state_dict(),
            "ema_updates": self.ema.updates,
            "optimizer": self.optimizer.state_dict(),
            "scaler": self.scaler.state_dict(),
            "epoch": self.epoch,
            "partial": partial,
            "best_fitness": self.best,
            "history": self.history,
            "settings": self.settings,
            **self.extra,
        }
