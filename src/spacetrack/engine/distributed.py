"""Training in several processes with torch's DistributedDataParallel: one process per GPU (`nccl`) or
CPU processes (`gloo`).

A launcher starts the processes and tells each its place through the environment: `torchrun` sets
RANK, WORLD_SIZE, LOCAL_RANK and LOCAL_WORLD_SIZE (with MASTER_ADDR and MASTER_PORT); in a SLURM job
that submitit started with several tasks (the `slurm` Hydra launcher) they are derived from the job's
tasks. Without them a training is the usual single process and nothing here changes it.

The batch size of the configs is the global batch. Every process draws the same order of samples
for an epoch; each global batch of that order is cut into one consecutive share per process
(`shard_of_batches`), so the samples of a step, and the order of the steps, do not depend on the
number of processes. Rank 0 alone validates, writes checkpoints and logs to MLflow.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator, Sequence
from contextlib import AbstractContextManager, contextmanager, nullcontext
from dataclasses import dataclass
from datetime import timedelta
from typing import TypeVar

import torch
import torch.distributed as dist
from torch import nn
from torch.nn.parallel import DistributedDataParallel
from torch.utils.data import RandomSampler, Sampler

from spacetrack.device import resolve_device

# How long a process waits for the others at a collective: rank 0 validates alone after every epoch.
TIMEOUT = timedelta(hours=2)
T = TypeVar("T")


@dataclass(frozen=True)
class World:
    """This process's place among those of a training: `rank` of `size` in all, `local_rank` of
    `local_size` on this machine."""

    rank: int = 0
    size: int = 1
    local_rank: int = 0
    local_size: int = 1

    @property
    def is_main(self) -> bool:
        """Whether this process validates, writes the files and logs to MLflow (rank 0)."""
        return self.rank == 0

    @property
    def distributed(self) -> bool:
        return self.size > 1


def _export_slurm_tasks() -> None:
    """In a submitit SLURM job of several tasks, set torch's variables (RANK, WORLD_SIZE, ...,
    MASTER_ADDR: the job's first node, MASTER_PORT: drawn from the job id) from the job's tasks."""
    if "RANK" in os.environ or os.environ.get("SUBMITIT_EXECUTOR") != "slurm":
        return
    if int(os.environ.get("SLURM_NTASKS", "1")) > 1:
        from submitit.helpers import TorchDistributedEnvironment

        TorchDistributedEnvironment().export(set_cuda_visible_devices=False)


def launched_world() -> World:
    """Where the launcher put this process (see the module docstring); World() when it is alone."""
    _export_slurm_tasks()
    env = os.environ
    size = int(env.get("WORLD_SIZE", "1"))
    return World(
        rank=int(env.get("RANK", "0")),
        size=size,
        local_rank=int(env.get("LOCAL_RANK", "0")),
        local_size=int(env.get("LOCAL_WORLD_SIZE", str(size))),
    )


def current_world() -> World:
    """The world of the initialised process group (local ranks from the environment); World() without
    one."""
    if not (dist.is_available() and dist.is_initialized()):
        return World()
    size = dist.get_world_size()
    return World(
        rank=dist.get_rank(),
        size=size,
        local_rank=int(os.environ.get("LOCAL_RANK", "0")),
        local_size=int(os.environ.get("LOCAL_WORLD_SIZE", str(size))),
    )


def require_gpus(processes: int, *, key: str) -> int:
    """The number of GPUs here, refused when it is less than `processes` (one process per GPU on this
    machine; `key`: the device setting that would train on the CPU instead)."""
    count = torch.cuda.device_count() if torch.cuda.is_available() else 0
    if processes > count:
        instead = f"; {key}=cpu trains in {processes} CPU processes instead" if count == 0 else ""
        raise ValueError(
            f"{processes} training processes on this machine (GPUS / --nproc_per_node) need {processes} GPUs, "
            f"but it has {count or 'none'}{instead}"
        )
    return count


def process_device(setting: str, world: World, *, key: str) -> torch.device:
    """The device of this process for the config value `setting` of `key` (`auto`, `cpu`, `cuda`):
    alone, as `resolve_device` says; among several, GPU `local_rank` (made current) for `auto` and
    `cuda`, the CPU for `cpu`. Refused: more processes on this machine than GPUs (see `require_gpus`),
    one pinned GPU (`cuda:1`) for several processes."""
    device = resolve_device(setting)
    if not world.distributed or (device.type != "cuda" and setting != "auto"):
        return device
    if device.index is not None:
        raise ValueError(
            f"{key}={setting} pins one GPU, but each of the {world.size} processes takes its own: "
            f"use {key}=auto or cuda"
        )
    require_gpus(world.local_size, key=key)
    torch.cuda.set_device(world.local_rank)
    return torch.device("cuda", world.local_rank)


@contextmanager
def process_group(setting: str, *, key: str) -> Iterator[World]:
    """Join the other processes of the training for the block (`nccl` when they run on GPUs, `gloo` on
    the CPU; `setting` is the config's device value named by `key`) and yield this process's world.

    A single process yields World() and joins nothing; a group that is already initialised is used
    as it is. Other ranks print nothing on stdout from here on (errors still go to stderr). At the
    end of the block the processes wait for each other, then leave the group.
    """
    world = launched_world()
    if not world.distributed or dist.is_initialized():
        yield current_world() if world.distributed else world
        return
    device = process_device(setting, world, key=key)
    dist.init_process_group("nccl" if device.type == "cuda" else "gloo", timeout=TIMEOUT)
    if not world.is_main:
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 - for the rest of the process
    try:
        yield world
        dist.barrier()
    finally:
        dist.destroy_process_group()


def check_batch_split(batch_size: int, world: World, *, key: str) -> int:
    """The share of each process of the global batch `batch_size` (images): refused unless it divides
    evenly."""
    if batch_size % world.size:
        below = batch_size // world.size * world.size
        raise ValueError(
            f"{key}={batch_size} is the global batch, to be split evenly across {world.size} processes: "
            f"use a multiple of {world.size} such as {below or world.size} or {below + world.size}"
        )
    return batch_size // world.size


def shard_sizes(count: int, parts: int) -> list[int]:
    """`count` items in `parts` consecutive shares as even as can be, the larger ones first."""
    base, extra = divmod(count, parts)
    return [base + (rank < extra) for rank in range(parts)]


def shard_of_batches(order: Sequence[int], *, batch_size: int, world: World, drop_last: bool) -> list[int]:
    """This process's indices of an epoch: its consecutive share of every global batch of `batch_size`
    entries of `order`, batch after batch. An incomplete last batch is left out with `drop_last`, and
    also when it has fewer entries than processes (some would get none); otherwise it is shared as
    evenly as can be. One process gets `order` itself (minus a dropped last batch)."""
    kept = []
    for start in range(0, len(order), batch_size):
        batch = list(order[start : start + batch_size])
        if len(batch) < (batch_size if drop_last else world.size):
            break
        sizes = shard_sizes(len(batch), world.size)
        begin = sum(sizes[: world.rank])
        kept.extend(batch[begin : begin + sizes[world.rank]])
    return kept


def batches_per_epoch(count: int, *, batch_size: int, world: World) -> int:
    """Global batches of an epoch of `count` samples without `drop_last` (see `shard_of_batches`)."""
    full, rest = divmod(count, batch_size)
    return full + (rest >= world.size)


class ShardedRandomSampler(Sampler[int]):
    """`RandomSampler(generator=generator)`'s order of each epoch, cut by `shard_of_batches`: with one
    process the same indices in the same order, drawn from `generator` in the same way."""

    def __init__(
        self, num_samples: int, *, batch_size: int, world: World, generator: torch.Generator, drop_last: bool
    ) -> None:
        self.num_samples, self.batch_size, self.world = num_samples, batch_size, world
        self.generator, self.drop_last = generator, drop_last

    def __iter__(self) -> Iterator[int]:
        order = list(RandomSampler(range(self.num_samples), generator=self.generator))
        yield from shard_of_batches(
            order, batch_size=self.batch_size, world=self.world, drop_last=self.drop_last
        )

    def __len__(self) -> int:
        order = range(self.num_samples)
        return len(
            shard_of_batches(order, batch_size=self.batch_size, world=self.world, drop_last=self.drop_last)
        )


def distribute_model(model: nn.Module, device: torch.device, world: World, *, sync_bn: bool) -> nn.Module:
    """What the training calls forward on: `model` itself alone; among several processes `model` in
    DistributedDataParallel (gradients averaged at backward), its BatchNorm layers synchronised across
    the processes with `sync_bn` (CUDA only; converted in place, so build the optimiser afterwards)."""
    if not world.distributed:
        return model
    if sync_bn:
        if device.type != "cuda":
            raise ValueError("sync_bn=true needs GPU processes (nccl); on the CPU leave it false")
        nn.SyncBatchNorm.convert_sync_batchnorm(model)
    return DistributedDataParallel(model, device_ids=[device.index] if device.type == "cuda" else None)


def broadcast_object(value: T, world: World) -> T:
    """Rank 0's `value` on every process (a picklable object)."""
    if not world.distributed:
        return value
    holder = [value]
    dist.broadcast_object_list(holder, src=0)
    return holder[0]


def sum_across(values: torch.Tensor, world: World) -> torch.Tensor:
    """The elementwise sum of `values` over all processes (a new CPU tensor; `values` is untouched)."""
    if not world.distributed:
        return values.clone()
    total = values.detach().clone().to(_collective_device())
    dist.all_reduce(total)
    return total.cpu()


def rank0_decides(flag: bool, world: World) -> bool:
    """Rank 0's `flag` on every process (a decision such as 'a checkpoint is due' that must agree)."""
    if not world.distributed:
        return flag
    decision = torch.tensor([int(flag)], device=_collective_device())
    dist.broadcast(decision, src=0)
    return bool(decision.item())


def _collective_device() -> torch.device:
    """Where tensors of a collective live: the current GPU under nccl, the CPU under gloo."""
    return (
        torch.device("cuda", torch.cuda.current_device())
        if dist.get_backend() == "nccl"
        else torch.device("cpu")
    )


def collectives_in_step(model: nn.Module, synchronise: bool) -> AbstractContextManager:
    """A context for one backward pass: DistributedDataParallel's `no_sync` (gradients stay local, to
    be averaged at the step's last micro-batch) unless `synchronise`; a no-op for a plain module."""
    if synchronise or not isinstance(model, DistributedDataParallel):
        return nullcontext()
    return model.no_sync()


def main(argv: list[str] | None = None) -> None:
    """`python -m spacetrack.engine.distributed GPUS KEY`: refuse, before any process starts, a GPUS
    larger than this machine's GPUs (what `make train GPUS=N` checks first); KEY: the device setting."""
    from spacetrack.cli import UserError, user_errors_exit

    gpus, key = argv if argv is not None else sys.argv[1:]
    with user_errors_exit():
        if not gpus.isdigit() or int(gpus) < 1:
            raise UserError(f"GPUS={gpus}: expected a number of GPUs, 1 or more")
        require_gpus(int(gpus), key=key)


if __name__ == "__main__":
    main()
