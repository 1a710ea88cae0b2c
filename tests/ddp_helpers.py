"""Run a test's worker in several CPU processes joined on gloo, as torchrun would start them."""

from __future__ import annotations

import os
import socket
import sys
import time
from collections.abc import Callable

import torch
import torch.multiprocessing as mp


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _as_launched(rank: int, worker: Callable, world_size: int, port: int, args: tuple) -> None:
    """In process `rank`: torchrun's environment variables, one torch thread, then `worker(*args)`."""
    os.environ.update(
        RANK=str(rank),
        WORLD_SIZE=str(world_size),
        LOCAL_RANK=str(rank),
        LOCAL_WORLD_SIZE=str(world_size),
        MASTER_ADDR="127.0.0.1",
        MASTER_PORT=str(port),
    )
    torch.set_num_threads(1)
    worker(*args)


def run_in_processes(worker: Callable, world_size: int, *args, timeout: float = 180.0) -> None:
    """Call `worker(*args)` (a module-level function) in `world_size` processes that find each other
    through torchrun's variables on a free local port; raise when one fails, and kill them all when they
    are not done after `timeout` seconds. Forked where the system forks (no second import of torch and
    the package, which takes longer than the tests' trainings), spawned elsewhere."""
    context = mp.start_processes(
        _as_launched,
        args=(worker, world_size, free_port(), args),
        nprocs=world_size,
        join=False,
        start_method="fork" if sys.platform == "linux" else "spawn",
    )
    deadline = time.monotonic() + timeout
    while not context.join(timeout=1.0):
        if time.monotonic() > deadline:
            for process in context.processes:
                process.kill()
            raise TimeoutError(f"{world_size} training processes were not done after {timeout:.0f} s")


def count_calls(targets: list[tuple[object, str]]) -> dict[str, int]:
    """Wrap each (module, function name) so that its calls are counted; the counts by name."""
    counts: dict[str, int] = {}
    for owner, name in targets:
        original = getattr(owner, name)
        counts[name] = 0

        def counted(*args, _original=original, _name=name, **kwargs):
            counts[_name] += 1
            return _original(*args, **kwargs)

        setattr(owner, name, counted)
    return counts
