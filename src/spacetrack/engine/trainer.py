"""The detector training loop: epochs of SGD with warm-up and EMA, validation, best/last checkpoints.

Everything random in an epoch (sample order, augmentation) is drawn from (seed, epoch), gradients never
cross an epoch boundary and the checkpoint holds the full optimiser, EMA and scaler state, so resuming
from `last.pt` after a kill gives the same weights as a run that was never interrupted.

With `max_minutes` the run fits a wall-clock budget: after every epoch the epochs still to come are
planned from the mean epoch time so far (training and validation) and the minutes left, never more than
`epochs`; the learning rate then decays over the planned epochs. The plan and the minutes spent are
saved in every checkpoint, so a resumed run keeps counting from where it stopped. Where the budget
binds, the result depends on the machine's speed (and a resumed run on its timings); where it does not,
nothing changes.

Launched in several processes (`torchrun`, see `engine.distributed`) it trains one model with
DistributedDataParallel: `batch_size` stays the global batch, each process takes its share of every
batch of the same (seed, epoch) order, and rank 0 alone validates and writes the checkpoints.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from torch import nn
from torch.utils.data import DataLoader, Dataset
from tqdm import tqdm

from spacetrack.data.yolo_dataset import collate
from spacetrack.engine.checkpoint import save_checkpoint
from spacetrack.engine.distributed import (
    World,
    batches_per_epoch,
    broadcast_object,
    check_batch_split,
    collectives_in_step,
    current_world,
    process_device,
    rank0_decides,
    shard_of_batches,
)
from spacetrack.engine.optim import lr_factor, set_learning_rates
from spacetrack.engine.precision import autocast_dtype
from spacetrack.engine.train_state import LossTally, RunState
from spacetrack.engine.validate import evaluate

EpochCallback = Callable[[dict[str, float], dict[str, Any], bool], None]


def fitness(metrics: dict[str, float]) -> float:
    """What `best.pt` maximises: mostly mAP@0.5:0.95, a little mAP@0.5."""
    return 0.1 * metrics["map50"] + 0.9 * metrics["map50_95"]


class Trainer:
    """Keyword arguments are the keys of `train.trainer` in the config; rates are per optimiser step,
    `batch_size` is the global batch (split evenly across the processes of a distributed training)."""

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
        sync_bn: bool = False,
        channels_last: bool = True,
        max_minutes: float | None = None,
    ) -> None:
        self.settings = {k: v for k, v in locals().items() if k != "self"}
        for key, value in self.settings.items():
            setattr(self, key, value)
        lr_factor(0, epochs=epochs, lrf=lrf, schedule=schedule)  # reject an unknown schedule now
        if max_minutes is not None and not max_minutes > 0:
            raise ValueError(
                f"train.trainer.max_minutes must be a positive number of minutes or null, got {max_minutes!r}"
            )
        self.clock = time.perf_counter  # what the budget is measured with (a test may replace it)

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
        started: float | None = None,
    ) -> dict[str, Any]:
        """Train `model` in place; return `history`, `best_fitness`, the checkpoint paths and
        `planned_epochs` (the epochs trained: `epochs`, or fewer where `max_minutes` bound).

        `run_settings` (data, image size, augmentation...) are stored with the trainer's settings; a
        resume with any of them changed is refused. `extra_state` (the MLflow run id) goes into every
        checkpoint as it is. `started`: the `clock` reading the budget counts from (the job's start, so
        that its data preparation counts too; default: now). In a distributed training every process
        calls it with the same arguments; rank 0 alone writes `out_dir` and calls `on_epoch_end`, every
        process gets the same result.
        """
        run = self._start(model, {**self.settings, **(run_settings or {})}, extra_state or {})
        if resume_from is not None:
            run.restore(resume_from)
        if self.max_minutes is None:
            run.planned = self.epochs  # a run that a budget cut, resumed without one, trains them all
        if started is not None:
            run.start_clock(started)
        weights = Path(out_dir) / "weights"
        if run.world.is_main:
            weights.mkdir(parents=True, exist_ok=True)
        val_loader = self._val_loader(val_set) if run.world.is_main else None
        num_batches = batches_per_epoch(len(train_set), batch_size=self.batch_size, world=run.world)
        epoch_seconds: list[float] = []
        epoch = run.epoch + 1
        while epoch < run.planned:
            began, left = self.clock(), num_batches - run.partial.get("batch", 0)
            train_set.set_epoch(epoch)
            components, images_per_s = self._train_epoch(
                run, loss_fn, train_set, epoch, num_batches, last_checkpoint=weights / "last.pt"
            )
            record, details = self._validate(run, loss_fn, val_loader, epoch, components, images_per_s)
            is_best = run.finish_epoch(epoch, record)
            # an epoch resumed mid-way ran only `left` of its batches: count it as a whole one
            epoch_seconds.append((self.clock() - began) * num_batches / max(left, 1))
            self._plan(run, epoch, epoch_seconds)
            if run.world.is_main:
                self._save_epoch(run, weights, is_best)
                if on_epoch_end is not None:
                    on_epoch_end(record, details, is_best)
            epoch += 1
        return {
            "history": run.history,
            "best_fitness": run.best,
            "best": weights / "best.pt",
            "last": weights / "last.pt",
            "planned_epochs": run.planned,
        }

    def _plan(self, run: RunState, epoch: int, epoch_seconds: list[float]) -> None:
        """After `epoch`: with `max_minutes`, the epochs the budget still fits (rank 0's plan on every
        process), and a line when that changes the plan."""
        if self.max_minutes is None:
            return
        spent, epoch_s = run.elapsed(), sum(epoch_seconds) / len(epoch_seconds)
        planned = planned_epochs(
            done=epoch + 1,
            configured=self.epochs,
            elapsed_s=spent,
            epoch_s=epoch_s,
            budget_s=60 * self.max_minutes,
        )
        planned = broadcast_object(planned, run.world)
        if planned != run.planned and run.world.is_main:
            print(
                f"train.trainer.max_minutes={self.max_minutes:g}: {spent / 60:.1f} min spent, an epoch "
                f"takes {epoch_s / 60:.1f} min, so {planned} of the "
                f"{self.epochs} epochs fit (the learning rate decays over them; "
                "train.trainer.max_minutes=null trains them all)",
                flush=True,
            )
        run.planned = planned

    def _start(self, model: nn.Module, settings: dict[str, Any], extra: dict[str, Any]) -> RunState:
        """This process's device, precision and share of the batch; the training state of `model`."""
        world = current_world()
        device = process_device(self.device, world, key="train.trainer.device")
        share = check_batch_split(self.batch_size, world, key="train.trainer.batch_size")
        model.to(device)
        if self.channels_last:
            model.to(memory_format=torch.channels_last)
        self.autocast = autocast_dtype(device, self.amp)
        processes = f"; {world.size} processes of {share} images a batch" if world.distributed else ""
        print(
            f"training on {device} in {self.autocast or torch.float32} (amp={self.amp}){processes}",
            flush=True,
        )
        return RunState(self, model, settings, extra, device, world)

    def _val_loader(self, val_set: Dataset) -> DataLoader:
        return DataLoader(val_set, batch_size=self.batch_size, num_workers=self.workers, collate_fn=collate)

    def _validate(
        self,
        run: RunState,
        loss_fn: Callable,
        val_loader: DataLoader | None,
        epoch: int,
        components: list[float],
        images_per_s: float,
    ) -> tuple[dict[str, float], dict[str, Any]]:
        """The epoch's record (losses, validation metrics of the EMA model, fitness, rate, images/s) and
        the validation details (PR curves, examples): computed by rank 0, the record sent to all."""
        details: dict[str, Any] = {}
        record = None
        if run.world.is_main:
            metrics, details = evaluate(
                run.ema.module,
                val_loader,
                device=run.device,
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
        return broadcast_object(record, run.world), details

    @staticmethod
    def _save_epoch(run: RunState, weights: Path, is_best: bool) -> None:
        save_checkpoint(weights / "last.pt", run.state())
        if is_best:
            save_checkpoint(weights / "best.pt", run.state())

    def _train_epoch(
        self,
        run: RunState,
        loss_fn: Callable,
        train_set: Dataset,
        epoch: int,
        num_batches: int,
        last_checkpoint: Path,
    ) -> tuple[list[float], float]:
        """One pass over the epoch's batches, from the first one a mid-epoch checkpoint had not done: mean
        [box, obj, cls] loss per image, and training images per second (of all processes). Every
        `checkpoint_minutes` a checkpoint is written at the next optimiser step, holding how far the
        epoch got."""
        skip = run.partial.pop("batch", 0)
        tally = LossTally(run.partial.pop("progress", None), run.world)
        run.partial.clear()
        target_lr = self.lr0 * lr_factor(epoch, epochs=run.planned, lrf=self.lrf, schedule=self.schedule)
        run.forward.train()
        run.optimizer.zero_grad()
        last_save = time.perf_counter()
        bar = tqdm(self._epoch_loader(train_set, epoch, skip, run.world), desc=f"epoch {epoch + 1}/{run.planned}",
                   unit="batch", disable=not (self.progress and run.world.is_main), leave=False, initial=skip,
                   total=num_batches)  # fmt: skip
        for i, (images, targets) in enumerate(bar, start=skip):
            self._set_rates(run, num_batches * epoch + i, num_batches, target_lr)
            step_ends = (i + 1) % run.accumulate == 0 or i + 1 == num_batches
            with collectives_in_step(run.forward, synchronise=step_ends):
                loss, components = self._forward(run, loss_fn, images, targets)
                if not torch.isfinite(loss):
                    raise _diverged(loss, epoch, i, last_checkpoint, resumed_at=skip)
                # Each process's loss is its share's (times its share of images); DDP averages the
                # gradients over the processes, so times their number gives the global batch's.
                run.scaler.scale(loss * run.world.size).backward()
            tally.add(components, len(images))
            if step_ends:
                run.step()
                last_save = self._checkpoint_if_due(
                    run, tally, last_checkpoint, i + 1, num_batches, last_save
                )
        return tally.epoch_means(run.world)

    def _epoch_loader(self, train_set: Dataset, epoch: int, skip: int, world: World) -> DataLoader:
        """This process's batches of the epoch's (seed, epoch) order from global batch `skip` on."""
        order = torch.randperm(
            len(train_set), generator=torch.Generator().manual_seed(self.seed * 100_003 + epoch)
        )
        mine = shard_of_batches(
            order.tolist()[skip * self.batch_size :], batch_size=self.batch_size, world=world, drop_last=False
        )
        return DataLoader(train_set, batch_size=self.batch_size // world.size, sampler=mine,
                          num_workers=self.workers, collate_fn=collate)  # fmt: skip

    def _set_rates(self, run: RunState, iteration: int, num_batches: int, target_lr: float) -> None:
        """Learning rates and momentum of batch `iteration` (counted over the whole run)."""
        set_learning_rates(
            run.optimizer,
            iteration=iteration,
            warmup_iterations=round(self.warmup_epochs * num_batches),
            target_lr=target_lr,
            momentum=self.momentum,
            warmup_momentum=self.warmup_momentum,
            warmup_bias_lr=self.warmup_bias_lr,
        )

    def _forward(
        self, run: RunState, loss_fn: Callable, images: torch.Tensor, targets: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(loss, [box, obj, cls] per image) of a batch of uint8 images and its target rows."""
        device = run.device
        x = images.to(device).float() / 255
        if self.channels_last:
            x = x.contiguous(memory_format=torch.channels_last)
        with torch.autocast(device.type, dtype=self.autocast, enabled=self.autocast is not None):
            raw = run.forward(x)
        return loss_fn([p.float() for p in raw], targets.to(device))

    def _checkpoint_if_due(
        self, run: RunState, tally: LossTally, path: Path, next_batch: int, num_batches: int, last_save: float
    ) -> float:
        """After an optimiser step: write `path` with how far the epoch got (`next_batch`) when rank 0
        last wrote it `checkpoint_minutes` ago or more and the epoch goes on; when it was last written."""
        if self.checkpoint_minutes is None or next_batch >= num_batches:
            return last_save
        now = time.perf_counter()
        if not rank0_decides(now - last_save >= 60 * self.checkpoint_minutes, run.world):
            return last_save
        progress = tally.totals(run.world)
        if run.world.is_main:
            save_checkpoint(path, run.state(partial={"batch": next_batch, "progress": progress}))
        return now


def planned_epochs(*, done: int, configured: int, elapsed_s: float, epoch_s: float, budget_s: float) -> int:
    """The epochs a run trains in all when `done` are finished after `elapsed_s` seconds of its budget of
    `budget_s`, an epoch taking `epoch_s`: those done and as many more as the time left holds whole,
    at most `configured`."""
    more = int(max(budget_s - elapsed_s, 0.0) // max(epoch_s, 1e-9))
    return max(done, min(configured, done + more))


def _diverged(
    loss: torch.Tensor, epoch: int, batch: int, last_checkpoint: Path, *, resumed_at: int
) -> FloatingPointError:
    """The error of a non-finite loss at `batch` of `epoch`, naming the checkpoint that is kept."""
    kept_at = f"{epoch} batch {resumed_at}" if resumed_at else (epoch - 1 if epoch else None)
    kept = f"{last_checkpoint} (epoch {kept_at}) is kept" if kept_at is not None else "no checkpoint yet"
    return FloatingPointError(
        f"training loss is {loss.item()} at epoch {epoch} batch {batch}; stopped, {kept}. Lower "
        "train.trainer.lr0 or check the labels."
    )
