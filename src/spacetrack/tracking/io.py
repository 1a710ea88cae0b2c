"""Detection files in, MOT results out.

A detection file is the reference DeepSORT layout: an N x (10 + D) float `.npy` array with rows
`frame,-1,x,y,w,h,confidence,-1,-1,-1` (box `tlwh` in pixels, 1-based frames in increasing order)
followed by a D-dimensional appearance feature (D may be 0). Results are MOT text rows
`frame,id,x,y,w,h,1,-1,-1,-1`.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from spacetrack.io import atomic_write_text

DETECTION_COLUMNS = ("frame", "-1", "x", "y", "w", "h", "confidence", "-1", "-1", "-1")
HEAD_COLUMNS = len(DETECTION_COLUMNS)
# The appearance feature after the head; frame, box and confidence are at the columns of a MOT row
# (`data.layout.FRAME`, `BOX`, `CONF`).
FEATURES = slice(HEAD_COLUMNS, None)
LAYOUT = "frame,-1,x,y,w,h,confidence,-1,-1,-1 followed by a D-dim feature"


class DetectionFileError(ValueError):
    """A detection file that does not follow the layout; the message names the file, row and value."""


def _column_name(c: int) -> str:
    return DETECTION_COLUMNS[c] if c < HEAD_COLUMNS else f"feature[{c - HEAD_COLUMNS}]"


def _check_finite(path: Path, dets: np.ndarray) -> None:
    bad = np.argwhere(~np.isfinite(dets))
    if not len(bad):
        return
    r, c = (int(v) for v in bad[0])
    feature_nan = np.isnan(dets[r, FEATURES])
    first = int(np.argmax(feature_nan)) if feature_nan.any() else -1
    if first > 0 and feature_nan[first:].all() and np.isfinite(dets[r, : HEAD_COLUMNS + first]).all():
        # NaN padding after a shorter feature: the rows were built with different feature sizes.
        raise DetectionFileError(
            f"{path}: row {r} has a {first}-dim feature (NaN-padded) but the file is "
            f"{feature_nan.size}-dim: the feature dimension must not change within a file"
        )
    raise DetectionFileError(f"{path}: row {r}, column {c} ({_column_name(c)}) is {dets[r, c]}")


def load_detections(path: str | Path) -> np.ndarray:
    """The validated (N, 10 + D) float64 detection array of `path`.

    Raises DetectionFileError (a ValueError) naming the file, row (0-based) and value for: a missing or
    unreadable file, a non-2-D or object array, fewer than 10 columns, no rows, NaN or infinite
    values, a width or height <= 0, a frame that is not a whole number >= 1, or frames out of order.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"detection file {path} not found")
    if path.stat().st_size == 0:
        raise DetectionFileError(f"{path}: empty file (0 bytes); expected an N x (10 + D) array: {LAYOUT}")
    with path.open("rb") as f:
        if f.read(6) != b"\x93NUMPY":
            raise DetectionFileError(f"{path}: not a readable .npy file (no NumPy header); expected {LAYOUT}")
    try:
        dets = np.load(path, allow_pickle=False)
    except ValueError as err:
        if "allow_pickle" in str(err):
            raise DetectionFileError(
                f"{path}: holds an object array (rows of different lengths, i.e. a feature dimension "
                f"that changes within the file?); expected an N x (10 + D) float array: {LAYOUT}"
            ) from err
        raise DetectionFileError(f"{path}: not a readable .npy file ({err})") from err
    except (OSError, EOFError) as err:
        raise DetectionFileError(f"{path}: not a readable .npy file ({err})") from err
    if dets.ndim != 2:
        raise DetectionFileError(f"{path}: array of shape {dets.shape}; expected N x (10 + D): {LAYOUT}")
    if dets.shape[1] < HEAD_COLUMNS:
        raise DetectionFileError(
            f"{path}: {dets.shape[1]} columns; expected at least {HEAD_COLUMNS}: {LAYOUT}"
        )
    if not len(dets):
        raise DetectionFileError(f"{path}: empty (0 rows); expected at least one detection: {LAYOUT}")
    if not np.issubdtype(dets.dtype, np.number):
        raise DetectionFileError(f"{path}: dtype {dets.dtype}; expected a float array")
    dets = dets.astype(np.float64)
    _check_finite(path, dets)
    for c in (4, 5):
        bad = np.flatnonzero(dets[:, c] <= 0)
        if len(bad):
            r = int(bad[0])
            raise DetectionFileError(f"{path}: row {r}, {_column_name(c)} = {dets[r, c]} is not positive")
    frames = dets[:, 0]
    bad = np.flatnonzero((frames != np.round(frames)) | (frames < 1))
    if len(bad):
        r = int(bad[0])
        raise DetectionFileError(f"{path}: row {r}, frame {frames[r]} is not a whole number >= 1")
    back = np.flatnonzero(np.diff(frames) < 0)
    if len(back):
        r = int(back[0]) + 1
        raise DetectionFileError(
            f"{path}: row {r}, frame {int(frames[r])} comes after frame {int(frames[r - 1])}; "
            "rows must be sorted by frame"
        )
    return dets


def iter_frames(dets: np.ndarray) -> Iterator[tuple[int, np.ndarray]]:
    """(frame, rows) for every frame from the first to the last in `dets`, empty frames included."""
    frames = dets[:, 0].astype(int)
    first, last = int(frames[0]), int(frames[-1])
    bounds = np.searchsorted(frames, np.arange(first, last + 2))
    for i, frame in enumerate(range(first, last + 1)):
        yield frame, dets[bounds[i] : bounds[i + 1]]


def format_mot_results(rows: np.ndarray) -> str:
    """MOT text for rows (frame, id, x, y, w, h): `frame,id,x,y,w,h,1,-1,-1,-1`, boxes to 0.01 px."""
    lines = [f"{int(f)},{int(i)},{x:.2f},{y:.2f},{w:.2f},{h:.2f},1,-1,-1,-1" for f, i, x, y, w, h in rows]
    return "".join(line + "\n" for line in lines)


def write_mot_results(path: str | Path, rows: np.ndarray) -> None:
    """Write rows (frame, id, x, y, w, h) to `path` atomically (its folder must exist)."""
    atomic_write_text(path, format_mot_results(np.asarray(rows, dtype=float).reshape(-1, 6)))
