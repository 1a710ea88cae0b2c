"""Reading the on-disk dataset layout (described in docs/contracts.md, "Dataset layout").

A dataset root holds `manifest.json` and one folder per sequence with `img/`, `gt/gt.txt`,
`gt/static.txt`, `labels/`, `masks/` and `seqinfo.ini`. Frame numbers are 1-based everywhere.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

MANIFEST = "manifest.json"
FORMAT_VERSION = 1
MOT_COLUMNS = ("frame", "id", "x", "y", "w", "h", "conf", "class", "visibility")
# Columns of a MOT row by name (box `tlwh` in pixels); the detection rows of `tracking.io` share the first
# seven (with id -1).
FRAME, ID, BOX, CONF, CLASS, VISIBILITY = 0, 1, slice(2, 6), 6, 7, 8
_MOT_DEFAULTS = np.array([np.nan] * 6 + [1.0, -1.0, -1.0])  # conf, class, visibility when absent


def frame_name(frame: int, ext: str) -> str:
    """File name of 1-based `frame`, e.g. frame_name(1, "jpg") == "000001.jpg"."""
    return f"{frame:06d}.{ext}"


def _read_image(path: str | Path, flags: int) -> np.ndarray:
    if not Path(path).is_file():
        raise FileNotFoundError(f"{path}: image not found")
    image = cv2.imread(str(path), flags)
    if image is None or image.size == 0:
        raise ValueError(f"{path}: cannot read image (empty, corrupt or not an image)")
    return image


def read_rgb(path: str | Path) -> np.ndarray:
    """RGB uint8 (H, W, 3) image at `path`; a missing, empty or unreadable file is an error naming it."""
    return cv2.cvtColor(_read_image(path, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def read_mask(path: str | Path) -> np.ndarray:
    """(H, W) uint8 single-channel image at `path` (a motion mask); errors as `read_rgb`."""
    return _read_image(path, cv2.IMREAD_GRAYSCALE)


def load_manifest(root: str | Path) -> dict:
    """The dataset manifest at `root`, with a clear error if it is missing or of another format."""
    path = Path(root) / MANIFEST
    if not path.is_file():
        raise FileNotFoundError(
            f"{path} not found: {root} is not a built dataset (make it with `make data` or "
            "`python -m spacetrack.build_data`)"
        )
    manifest = json.loads(path.read_text())
    version = manifest.get("format_version")
    if version != FORMAT_VERSION:
        raise ValueError(f"{path}: format_version {version!r}, expected {FORMAT_VERSION}")
    return manifest


def rendered_truth(manifest: dict) -> str | None:
    """What the boxes of a rendered dataset frame (its `data.truth`: "seen" or "silhouette"; datasets
    rendered before the key existed framed silhouettes), or None for a dataset not rendered here."""
    data = manifest.get("config", {}).get("data")
    return None if data is None else data.get("truth", "silhouette")


def check_rendered_truth(manifest: dict, root: str | Path, truth: str) -> None:
    """Refuse to use the dataset at `root` as `data.truth=<truth>` when it was rendered with another truth:
    its boxes are not the ones the config (and every setting recorded from it) says."""
    rendered = rendered_truth(manifest)
    if rendered is not None and rendered != truth:
        raise ValueError(
            f"{Path(root) / MANIFEST}: rendered with data.truth={rendered}, the config asks data.truth={truth}; "
            f"render it again (python -m spacetrack.build_data data.name={manifest.get('name')} overwrite=true) "
            f"or pass data.truth={rendered}"
        )


def split_sequences(manifest: dict, fold: int) -> tuple[list[str], list[str]]:
    """(training, validation) sequence names: fold `fold` validates, every other fold trains."""
    num_folds = int(manifest["num_folds"])
    if not isinstance(fold, (int, np.integer)) or not 0 <= fold < num_folds:
        raise ValueError(f"fold {fold!r} is outside 0..{num_folds - 1} (dataset {manifest.get('name')})")
    train = [s["name"] for s in manifest["sequences"] if s["fold"] != fold]
    val = [s["name"] for s in manifest["sequences"] if s["fold"] == fold]
    return train, val


def frame_paths(root: str | Path, seq: str, image_dir: str = "img") -> list[Path]:
    """Sorted image paths of sequence `seq` in folder `image_dir` (e.g. "img" or "img_dwt_hsv")."""
    folder = Path(root) / seq / image_dir
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder} not found (sequence {seq!r}, image folder {image_dir!r})")
    paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in (".jpg", ".jpeg", ".png"))
    if not paths:
        raise FileNotFoundError(f"{folder} holds no .jpg or .png frames")
    return paths


def read_mot(path: str | Path) -> np.ndarray:
    """MOT rows of `path` as an (N, 9) float64 array `frame,id,x,y,w,h,conf,class,visibility`.

    Reads ground truth and tracker results alike: 6 to 10 comma- or space-separated columns (the MOT15
    results layout has 10, the tenth is ignored); missing columns get conf 1, class -1, visibility -1
    (unknown). An empty file is zero rows. Raises ValueError naming the file, line and value for a line
    that is not numeric, has fewer than six columns, or holds NaN or infinite values.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"MOT file {path} not found")
    rows = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        fields = line.replace(",", " ").split()
        try:
            values = [float(v) for v in fields]
        except ValueError:
            raise ValueError(f"{path}: line {number} is not numeric: {line!r}") from None
        if not 6 <= len(values) <= 10:
            raise ValueError(
                f"{path}: line {number} has {len(values)} columns; expected 6 to 10 "
                f"({','.join(MOT_COLUMNS)}): {line!r}"
            )
        if not np.all(np.isfinite(values)):
            raise ValueError(f"{path}: line {number} holds a NaN or infinite value: {line!r}")
        row = _MOT_DEFAULTS.copy()
        row[: min(len(values), 9)] = values[:9]
        rows.append(row)
    return np.array(rows) if rows else np.zeros((0, len(MOT_COLUMNS)))
