"""Timing and report helpers shared by the benchmark scripts.

Each benchmark times its contenders in the same process and run, reports medians and spreads (this
machine is noisy), the ratio of each contender to the peer, and writes `reports/<name>.json` plus a
markdown table `reports/<name>.md`. The timed loops show a bar with the rate and the time left (on stderr,
updated between timed calls, never inside one).
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import time
from collections.abc import Callable
from datetime import datetime, timezone
from pathlib import Path

from tqdm import tqdm

REPORTS = Path(__file__).resolve().parents[1] / "reports"


def progress(total: int, desc: str, unit: str = "call") -> tqdm:
    """A bar over a benchmark's timed loop; it disappears when done, so the tables stay readable."""
    return tqdm(range(total), desc=desc[:40], unit=unit, leave=False, dynamic_ncols=True)


def time_call(
    fn: Callable[[], object], *, repeats: int, warmup: int = 3, desc: str = "timing"
) -> list[float]:
    """Wall-clock seconds of `repeats` calls of `fn` after `warmup` untimed calls."""
    for _ in range(warmup):
        fn()
    samples = []
    for _ in progress(repeats, desc) if repeats > 1 else range(repeats):
        t0 = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t0)
    return samples


def interleaved_samples(
    calls: dict, *, repeats: int
) -> tuple[dict[str, list[float]], dict[str, list[float]]]:
    """Wall-clock and CPU seconds per call of each contender, timed round-robin (one call of each per
    round), so that a change of machine load during the run hits every contender alike and the ratios
    stay fair. CPU time (all threads of this process) is less sensitive to other processes' load."""
    for call in calls.values():
        time_call(call, repeats=0, warmup=3)
    wall: dict[str, list[float]] = {name: [] for name in calls}
    cpu: dict[str, list[float]] = {name: [] for name in calls}
    for _ in progress(repeats, ", ".join(calls), unit="round"):
        for name, call in calls.items():
            t0 = time.process_time()
            wall[name] += time_call(call, repeats=1, warmup=0)
            cpu[name].append(time.process_time() - t0)
    return wall, cpu


def summarize(samples: list[float], scale: float = 1e3) -> dict[str, float]:
    """Median, quartiles, mean, min and max of `samples` multiplied by `scale` (default: seconds -> ms)."""
    xs = sorted(s * scale for s in samples)
    q = statistics.quantiles(xs, n=4) if len(xs) >= 2 else [xs[0]] * 3
    return {"median": q[1], "p25": q[0], "p75": q[2], "mean": statistics.fmean(xs), "min": xs[0],
            "max": xs[-1], "n": len(xs)}  # fmt: skip


def machine() -> dict[str, object]:
    """What the numbers were measured on."""
    info: dict[str, object] = {
        "platform": platform.platform(),
        "python": platform.python_version(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
    }
    try:
        import torch

        info["torch"] = torch.__version__
        info["torch_threads"] = torch.get_num_threads()
        if torch.cuda.is_available():
            info["gpu"] = torch.cuda.get_device_name(0)
    except ImportError:
        pass
    return info


def git_commit() -> str | None:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True, cwd=REPORTS.parent
        )
        return out.stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


def write_report(name: str, record: dict, table_md: str) -> tuple[Path, Path]:
    """Write reports/<name>.json (record plus machine, commit and time) and reports/<name>.md atomically."""
    REPORTS.mkdir(exist_ok=True)
    full = {
        "benchmark": name,
        "when": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "commit": git_commit(),
        "machine": machine(),
        **record,
    }
    paths = []
    for suffix, text in ((".json", json.dumps(full, indent=2) + "\n"), (".md", table_md)):
        path = REPORTS / f"{name}{suffix}"
        tmp = path.with_suffix(suffix + ".tmp")
        tmp.write_text(text)
        os.replace(tmp, path)
        paths.append(path)
    return paths[0], paths[1]


def markdown_table(header: list[str], rows: list[list[object]]) -> str:
    """A GitHub markdown table; floats are shown with three significant decimals."""

    def cell(v: object) -> str:
        return f"{v:.3f}" if isinstance(v, float) else str(v)

    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"
