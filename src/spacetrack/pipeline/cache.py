"""The detection cache: a sequence's detector boxes and re-ID features, saved once, re-tracked at will.

Per sequence `<folder>/<name>.npy` holds the detections in the DESIGN.md layout, an (N, 10 + D) float
array `frame,-1,x,y,w,h,confidence,-1,-1,-1` + D-dim re-ID feature (so `python -m
spacetrack.track_detections` runs on it alone); `<name>.flags.npy` (N, 2) int holds each row's
dynamic flag (1 = a moving target by the motion stage) and class; `<name>.json` says what made them:
detector (weights hash and settings), re-ID weights hash, enhancement, motion settings, source and
frame count. The JSON is written last, so a cache without a matching JSON is never read; every file is
written atomically.
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from spacetrack.io import atomic_path, atomic_write_text

log = logging.getLogger(__name__)
FORMAT = 1


class CacheMismatchError(ValueError):
    """A cache made by other weights or settings than configured, with rebuilding turned off."""


def config_hash(value: object) -> str:
    """Short hash of a JSON-serialisable value (a resolved config section)."""
    text = json.dumps(value, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class CacheKey:
    """Everything that changes a sequence's cached detections; two equal keys give equal caches."""

    detector: str
    reid: str
    enhance: str
    motion: str
    source: str

    def differences(self, other: dict) -> list[str]:
        mine = asdict(self)
        return [
            f"{k}: cached {other.get(k)!r}, configured {v!r}" for k, v in mine.items() if other.get(k) != v
        ]


class DetectionCache:
    """Detections per sequence under `folder`. `rebuild`: a cache made by other settings is rebuilt
    (True) or refused with the differences named (False)."""

    def __init__(self, folder: str | Path, *, rebuild: bool = True) -> None:
        self.folder, self.rebuild = Path(folder), rebuild

    def paths(self, name: str) -> tuple[Path, Path, Path]:
        """(detections .npy, flags .npy, sidecar .json) of sequence `name`."""
        return self.folder / f"{name}.npy", self.folder / f"{name}.flags.npy", self.folder / f"{name}.json"

    def load(self, name: str, key: CacheKey) -> tuple[np.ndarray, np.ndarray, int] | None:
        """(rows (N, 10 + D), flags (N, 2), number of frames) when a cache made by `key` exists, else None.

        A cache made by another key is None when `rebuild` (it will be overwritten), else a
        CacheMismatchError naming the sidecar and what differs. A damaged cache is rebuilt likewise.
        """
        rows_path, flags_path, meta_path = self.paths(name)
        if not meta_path.is_file():
            return None
        try:
            meta = json.loads(meta_path.read_text())
        except json.JSONDecodeError:
            meta = {}
        problems = (
            key.differences(meta.get("key", {})) if meta.get("format") == FORMAT else ["unreadable sidecar"]
        )
        rows = flags = None
        if not problems:
            try:
                rows, flags = np.load(rows_path), np.load(flags_path)
            except (OSError, ValueError) as err:
                problems = [f"unreadable arrays ({err})"]
            else:
                if len(rows) != len(flags) or len(rows) != meta.get("num_detections"):
                    problems = [
                        f"{len(rows)} detections, {len(flags)} flags, sidecar says {meta.get('num_detections')}"
                    ]
        if not problems:
            return rows, flags, int(meta["num_frames"])
        if not self.rebuild:
            raise CacheMismatchError(
                f"detection cache {meta_path} is stale: "
                + "; ".join(problems)
                + " (set cache.rebuild=true to rebuild it, or delete it)"
            )
        log.info("rebuilding detection cache %s: %s", meta_path, "; ".join(problems))
        return None

    def save(self, name: str, key: CacheKey, rows: np.ndarray, flags: np.ndarray, *, num_frames: int) -> None:
        """Write sequence `name`'s rows and flags, then the sidecar that makes them valid."""
        self.folder.mkdir(parents=True, exist_ok=True)
        rows_path, flags_path, meta_path = self.paths(name)
        meta_path.unlink(missing_ok=True)  # invalid until the new arrays are complete
        for path, array in ((rows_path, rows), (flags_path, flags)):
            with atomic_path(path) as tmp, tmp.open("wb") as f:
                np.save(f, array)
        meta = {
            "format": FORMAT,
            "key": asdict(key),
            "num_detections": len(rows),
            "num_frames": num_frames,
            "feature_dim": int(rows.shape[1]) - 10,
            "layout": "frame,-1,x,y,w,h,confidence,-1,-1,-1 + feature; flags: dynamic, class",
        }
        atomic_write_text(meta_path, json.dumps(meta, indent=2) + "\n")
