"""Per-stage wall-clock timing of the pipeline (enhance, detector, re-ID, motion, tracker, ...)."""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager


class StageTimer:
    """Accumulates seconds per named stage: `with timer("detector"): ...`."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[stage] += time.perf_counter() - start

    def ms_per_frame(self, num_frames: int) -> dict[str, float]:
        """{"<stage>_ms": milliseconds per frame} for every stage, plus their sum as "total_ms"."""
        n = max(num_frames, 1)
        out = {f"{stage}_ms": 1e3 * s / n for stage, s in self.seconds.items()}
        out["total_ms"] = 1e3 * sum(self.seconds.values()) / n
        return out
