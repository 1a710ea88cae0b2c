"""The detection cache: a sequence's detector boxes, re-ID features and motion blobs, saved once, re-tracked
at will.

Per sequence, two parts, each valid only with its sidecar, which is written last:
- what the networks made: `<folder>/<name>.npy` holds the detections in the reference DeepSORT layout (`frame,-1,x,y,w,h,confidence,-1,-1,-1` + features), an
  (N, 10 + D) float array `frame,-1,x,y,w,h,confidence,-1,-1,-1` + D-dim re-ID feature (so `python -m
  spacetrack.track_detections` runs on it alone), `<name>.classes.npy` (N,) each row's class, and
  `<name>.json` names the detector (weights hash and settings), re-ID weights, enhancement, source and
  frame count;
- what the motion stage made, one pair per motion setting: `<name>.blobs-<motion hash>.npy` (B, 8)
  `frame, cx, cy, x, y, w, h, area` (the moving blobs each frame's detections are matched with; frames
  1-based) and `<name>.blobs-<motion hash>.json` naming the motion settings and the source.
The dynamic flags are not stored: they come from the boxes and the blobs with the configured thresholds
(`conf/motion/dynamic.yaml`), so a new threshold re-tracks from the cache, and new motion settings re-run the motion
stage only, never a network. Every file is written atomically.
"""

from __future__ import annotations

import hashlib
import json
import logging
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from spacetrack.io import atomic_path, atomic_write_text
from spacetrack.motion.blobs import Blob

log = logging.getLogger(__name__)
FORMAT = 2
BLOB_COLUMNS = "frame, cx, cy, x, y, w, h, area"


class CacheMismatchError(ValueError):
    """A cache made by other weights or settings than configured, with rebuilding turned off."""


def config_hash(value: object) -> str:
    """Short hash of a JSON-serialisable value (a resolved config section)."""
    text = json.dumps(value, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class CacheKey:
    """Everything that changes a sequence's cached detections; two equal keys give equal caches.

    `motion` keys the blobs only: the detections stay valid when it changes.
    """

    detector: str
    reid: str
    enhance: str
    motion: str
    source: str

    def networks(self) -> dict[str, str]:
        return {k: v for k, v in asdict(self).items() if k != "motion"}

    def blobs(self) -> dict[str, str]:
        return {"motion": self.motion, "source": self.source}


@dataclass
class CachedSequence:
    """rows (N, 10 + D) and classes (N,) of frames 1..num_frames; `blobs` each frame's moving blobs (a
    list per frame; None for a frame means no motion stage: every detection counts as dynamic), or None
    when the motion stage must run again."""

    rows: np.ndarray
    classes: np.ndarray
    num_frames: int
    blobs: list[list[Blob] | None] | None = None


def blob_table(blobs: list[list[Blob] | None]) -> np.ndarray:
    """(B, 8) float64 `frame, cx, cy, x, y, w, h, area` of per-frame blob lists (frame 1 first)."""
    rows = [
        (frame, *b.centroid, *b.tlwh, b.area)
        for frame, frame_blobs in enumerate(blobs, start=1)
        for b in frame_blobs or ()
    ]
    return np.array(rows, dtype=np.float64).reshape(-1, 8)


def blobs_by_frame(table: np.ndarray, num_frames: int) -> list[list[Blob]]:
    """The per-frame blob lists of frames 1..num_frames from a `blob_table`."""
    out: list[list[Blob]] = [[] for _ in range(num_frames)]
    for frame, cx, cy, x, y, w, h, area in table.tolist():
        out[int(frame) - 1].append(Blob((cx, cy), (int(x), int(y), int(w), int(h)), area))
    return out


def _differences(expected: dict, meta: dict) -> list[str]:
    if meta.get("format") != FORMAT:
        return [f"format {meta.get('format')!r}, this version reads {FORMAT}"]
    cached = meta.get("key", {})
    return [
        f"{k}: cached {cached.get(k)!r}, configured {v!r}" for k, v in expected.items() if cached.get(k) != v
    ]


def _read_meta(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return {}


def _save_arrays(*pairs: tuple[Path, np.ndarray]) -> None:
    for path, array in pairs:
        with atomic_path(path) as tmp, tmp.open("wb") as f:
            np.save(f, array)


class DetectionCache:
    """Detections per sequence under `folder`. `rebuild`: a cache made by other settings is rebuilt
    (True) or refused with the differences named (False)."""

    def __init__(self, folder: str | Path, *, rebuild: bool = True) -> None:
        self.folder, self.rebuild = Path(folder), rebuild

    def paths(self, name: str, key: CacheKey) -> dict[str, Path]:
        """The files of sequence `name`: rows, classes, meta (the detections' sidecar), and blobs,
        blobs_meta of `key`'s motion settings (one pair per setting, so a sweep over motion settings
        computes each setting's blobs once)."""
        files = {"rows": ".npy", "classes": ".classes.npy", "meta": ".json"}
        files |= {"blobs": f".blobs-{key.motion}.npy", "blobs_meta": f".blobs-{key.motion}.json"}
        return {part: self.folder / f"{name}{suffix}" for part, suffix in files.items()}

    def load(self, name: str, key: CacheKey) -> CachedSequence | None:
        """The cached detections of `name` made by `key` (with the blobs when they match too), or None.

        A part made by another key is missing (None, or `blobs` None) when `rebuild` (it will be
        overwritten), else a CacheMismatchError naming the sidecar and what differs. A damaged part is
        rebuilt likewise.
        """
        paths = self.paths(name, key)

        def check(meta: dict, arrays: list[np.ndarray]) -> str | None:
            rows, classes = arrays
            if len(rows) == len(classes) == meta.get("num_detections"):
                return None
            return (
                f"{len(rows)} detections, {len(classes)} classes, sidecar says {meta.get('num_detections')}"
            )

        part = self._read_part(paths["meta"], key.networks(), [paths["rows"], paths["classes"]], check)
        if part is None:
            return None
        meta, (rows, classes) = part
        cached = CachedSequence(rows, classes, int(meta["num_frames"]))
        cached.blobs = self._load_blobs(paths, key, cached.num_frames)
        return cached

    def _load_blobs(self, paths: dict[str, Path], key: CacheKey, num_frames: int) -> list | None:
        def check(meta: dict, arrays: list[np.ndarray]) -> str | None:
            (table,) = arrays
            if table.ndim != 2 or table.shape[1] != 8 or len(table) != meta.get("num_blobs"):
                return f"blob table of shape {table.shape}, sidecar says {meta.get('num_blobs')} rows"
            if len(table) and not (table[:, 0].min() >= 1 and table[:, 0].max() <= num_frames):
                return f"blob frames {table[:, 0].min():g}-{table[:, 0].max():g} outside 1-{num_frames}"
            return None

        part = self._read_part(paths["blobs_meta"], key.blobs(), [paths["blobs"]], check)
        if part is None:
            return None
        meta, (table,) = part
        if not meta.get("motion_stage", True):
            return [None] * num_frames
        return blobs_by_frame(table, num_frames)

    def _read_part(
        self,
        meta_path: Path,
        expected: dict[str, str],
        array_paths: list[Path],
        check: Callable[[dict, list[np.ndarray]], str | None],
    ) -> tuple[dict, list[np.ndarray]] | None:
        """(sidecar, arrays) of one part when its sidecar exists, names `expected` and `check` finds
        nothing wrong with the arrays (it returns the problem); else None, or a CacheMismatchError when
        not `rebuild`."""
        if not meta_path.is_file():
            return None
        meta = _read_meta(meta_path)
        problems = _differences(expected, meta)
        if not problems:
            try:
                arrays = [np.load(path) for path in array_paths]
            except (OSError, ValueError) as err:
                problems = [f"unreadable arrays ({err})"]
            else:
                problem = check(meta, arrays)
                problems = [problem] if problem else []
        if problems:
            self._stale(meta_path, problems)
            return None
        return meta, arrays

    def _stale(self, meta_path: Path, problems: list[str]) -> None:
        if not self.rebuild:
            raise CacheMismatchError(
                f"detection cache {meta_path} is stale: "
                + "; ".join(problems)
                + " (set cache.rebuild=true to rebuild it, or delete it)"
            )
        log.info("rebuilding detection cache %s: %s", meta_path, "; ".join(problems))

    def save(
        self, name: str, key: CacheKey, rows: np.ndarray, classes: np.ndarray, *, num_frames: int
    ) -> None:
        """Write sequence `name`'s rows and classes, then the sidecar that makes them valid."""
        self.folder.mkdir(parents=True, exist_ok=True)
        paths = self.paths(name, key)
        paths["meta"].unlink(missing_ok=True)  # invalid until the new arrays are complete
        _save_arrays((paths["rows"], rows), (paths["classes"], classes))
        meta = {
            "format": FORMAT,
            "key": key.networks(),
            "num_detections": len(rows),
            "num_frames": num_frames,
            "feature_dim": int(rows.shape[1]) - 10,
            "layout": "frame,-1,x,y,w,h,confidence,-1,-1,-1 + feature; classes: one per row",
        }
        atomic_write_text(paths["meta"], json.dumps(meta, indent=2) + "\n")

    def save_blobs(self, name: str, key: CacheKey, blobs: list[list[Blob] | None]) -> None:
        """Write the per-frame moving blobs of sequence `name` (None per frame: no motion stage)."""
        self.folder.mkdir(parents=True, exist_ok=True)
        paths = self.paths(name, key)
        paths["blobs_meta"].unlink(missing_ok=True)
        table = blob_table(blobs)
        _save_arrays((paths["blobs"], table))
        meta = {
            "format": FORMAT,
            "key": key.blobs(),
            "num_blobs": len(table),
            "num_frames": len(blobs),
            "motion_stage": not blobs or blobs[0] is not None,
            "layout": BLOB_COLUMNS,
        }
        atomic_write_text(paths["blobs_meta"], json.dumps(meta, indent=2) + "\n")
