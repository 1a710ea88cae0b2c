"""Reading MOT text files (ground truth and tracker results) for evaluation."""

from __future__ import annotations

from pathlib import Path

import numpy as np

# frame,id,x,y,w,h,conf,class,visibility; results files carry at least the first six.
MOT_COLUMNS = ("frame", "id", "x", "y", "w", "h", "conf", "class", "visibility")
_DEFAULTS = np.array([np.nan, np.nan, np.nan, np.nan, np.nan, np.nan, 1.0, -1.0, -1.0])


def read_mot_file(path: str | Path) -> np.ndarray:
    """MOT rows of `path` as an (N, 9) float64 array `frame,id,x,y,w,h,conf,class,visibility`.

    Accepts 6 to 10 comma- or space-separated columns (the MOT15 results layout has 10, the tenth is
    ignored); missing columns get conf 1, class -1, visibility -1 (unknown). An empty file is zero rows.
    Raises ValueError naming the file, line and value for a line that is not numeric, has fewer than
    six columns, or holds NaN or infinite values.
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
        row = _DEFAULTS.copy()
        row[: min(len(values), 9)] = values[:9]
        rows.append(row)
    return np.array(rows) if rows else np.zeros((0, len(MOT_COLUMNS)))
