"""What a detector training carries from step to step: the model with its optimiser, EMA and scaler,
the epochs done, and the loss tally of the epoch in progress; what a checkpoint saves and a resume
restores (see `engine.trainer` for the loop that drives them)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch
from torch import nn

from spacetrack.engine.checkpoint import load_checkpoint, settings_differences
from spacetrack.engine.distributed import World, distribute_model, sum_across
from spacetrack.engine.optim import ModelEMA, build_optimizer

if TYPE_CHECKING:
    from spacetrack.engine.trainer import Trainer


class LossTally:
    """An epoch's [box, obj, cls] loss sums (per-image means times images) and images so far, and its
    training seconds. Each process counts its own; rank 0 also what a mid-epoch checkpoint it resumes
    from had counted (`progress`: sums, images, seconds, over all processes)."""

    def __init__(self, progress: tuple[torch.Tensor, int, float] | None, world: World) -> None:
        resumed = progress is not None and world.is_main
        self.sums, self.seen, self.elapsed = progress if resumed else (torch.zeros(3), 0, 0.0)
        self.started = time.perf_counter()

    def add(self, components: torch.Tensor, images: int) -> None:
        self.sums += components.cpu() * images
        self.seen += images

    def totals(self, world: World) -> tuple[torch.Tensor, int, float]:
        """(loss sums, images) of all processes, and the seconds so far (collective: every process
        calls it)."""
        counts = sum_across(torch.cat((self.sums, torch.tensor([float(self.seen)]))), world)
        return counts[:3], int(counts[3]), self.elapsed + time.perf_counter() - self.started

    def epoch_means(self, world: World) -> tuple[list[float], float]:
        """Mean [box, obj, cls] loss per image and images per second, over all processes."""
        sums, seen, elapsed = self.totals(world)
        return (sums / max(seen, 1)).tolist(), seen / max(elapsed, 1e-9)


class RunState:
    """What a training carries from step to step and saves: the model, its optimiser, EMA and scaler,
    the last finished epoch, the best fitness, the history, and how far an unfinished epoch got; the
    process's world and device, and `forward`: the model, or its DDP wrapper in several processes."""

    def __init__(
        self,
        trainer: Trainer,
        model: nn.Module,
        settings: dict,
        extra: dict,
        device: torch.device,
        world: World,
    ) -> None:
        self.model, self.settings, self.extra, self.device, self.world = model, settings, extra, device, world
        self.forward = distribute_model(model, device, world, sync_bn=trainer.sync_bn)
        self.accumulate = max(round(trainer.nbs / trainer.batch_size), 1)
        self.grad_clip = trainer.grad_clip
        decay = trainer.weight_decay * trainer.batch_size * self.accumulate / trainer.nbs
        self.optimizer = build_optimizer(
            model, lr0=trainer.lr0, momentum=trainer.momentum, weight_decay=decay
        )
        self.ema = ModelEMA(model, decay=trainer.ema_decay, tau=trainer.ema_tau)
        self.scaler = torch.amp.GradScaler("cuda", enabled=trainer.amp and device.type == "cuda")
        self.epoch, self.best, self.history, self.partial = -1, -1.0, [], {}
        self.planned = trainer.epochs  # the epochs the run trains: fewer where a time budget binds
        self.spent_before = 0.0  # seconds of the budget spent before this process went on with the run
        self.clock = trainer.clock
        self.clock_start = self.clock()

    def start_clock(self, started: float) -> None:
        """Count this process's share of the budget from the trainer's clock reading `started`."""
        self.clock_start = started

    def elapsed(self) -> float:
        """Seconds of the run's time budget spent: before a resume and in this process."""
        return self.spent_before + self.clock() - self.clock_start

    def restore(self, path: str | Path) -> None:
        """Continue from the checkpoint at `path`; refuse it when its settings differ. One of another
        number of processes is taken: the batches and their order do not depend on it."""
        state = load_checkpoint(path, arch=self.model.arch)
        changed = settings_differences(state, self.settings)
        if changed:
            raise ValueError(f"cannot resume {path} with other settings: {changed}")
        before = state.get("world_size", 1)
        if before != self.world.size:
            print(f"resuming {path}, trained in {before} process(es), in {self.world.size}", flush=True)
        self.model.load_state_dict(state["model"])
        self.ema.module.load_state_dict(state["ema"])
        self.ema.updates = state["ema_updates"]
        self.optimizer.load_state_dict(state["optimizer"])
        self.scaler.load_state_dict(state["scaler"])
        self.epoch, self.best, self.history = state["epoch"], state["best_fitness"], state["history"]
        self.partial = dict(state.get("partial") or {})
        self.planned = state.get("planned_epochs", self.planned)
        self.spent_before = state.get("elapsed_s", 0.0)

    def step(self) -> None:
        """One optimiser step on the gradients so far (unscaled, clipped), then the EMA update."""
        self.scaler.unscale_(self.optimizer)
        nn.utils.clip_grad_norm_(self.model.parameters(), max_norm=self.grad_clip)
        self.scaler.step(self.optimizer)
        self.scaler.update()
        self.optimizer.zero_grad()
        self.ema.update(self.model)

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
            "planned_epochs": self.planned,
            "elapsed_s": self.elapsed(),
            "partial": partial,
            "best_fitness": self.best,
            "history": self.history,
            "settings": self.settings,
            "world_size": self.world.size,
            **self.extra,
        }
