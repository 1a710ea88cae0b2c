"""Offline post-processing of a sequence's tracks, once the whole sequence has been tracked.

Beyond the paper, and never mixed with the online results: it needs frames that come after the one it
changes, so a live tracker cannot do it. Two steps, as StrongSORT++ does them:

- **Backfill**: a track is output only once it is confirmed (`n_init` hits) and, with the track-level
  dynamic decision, once it is found dynamic. The frames before that, where the tracker had already
  matched the track to a detection, are given back to it (the boxes of those detections).
- **Gap interpolation**: a gap of at most `max_gap` frames inside a track (a missed detection, a short
  occlusion) is filled by linear interpolation of the box between the frames on either side, and,
  optionally, each track's boxes are then smoothed by Gaussian-process regression over time (GSI:
  Gaussian-smoothed interpolation) with an RBF kernel of `smooth_frames` frames.

Rows are (frame, track id, x, y, w, h), box `tlwh` in pixels, as the trackers write them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class OfflineSettings:
    """backfill: give each output track its matched frames before its first output.
    max_gap: longest gap (missing frames) inside a track that is filled; 0 fills none.
    smooth_frames: RBF length scale (frames) of the Gaussian-process smoothing; None smooths nothing.
    """

    backfill: bool = True
    max_gap: int = 20
    smooth_frames: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.max_gap, int) or isinstance(self.max_gap, bool) or self.max_gap < 0:
            raise ValueError(f"offline.max_gap must be a whole number >= 0, got {self.max_gap!r}")
        if self.smooth_frames is not None and not self.smooth_frames > 0:
            raise ValueError(f"offline.smooth_frames must be > 0 or null, got {self.smooth_frames!r}")


def backfill(rows: np.ndarray, matched: np.ndarray) -> np.ndarray:
    """`rows` with, for each track id in them, the rows of `matched` of that id on frames before its first
    row in `rows`. matched: rows of every track matched to a detection on each frame (output or not)."""
    rows = _rows(rows)
    matched = _rows(matched)
    if not len(rows) or not len(matched):
        return rows
    first = {tid: rows[rows[:, 1] == tid, 0].min() for tid in np.unique(rows[:, 1])}
    earlier = np.array([first.get(tid, -np.inf) > f for f, tid in matched[:, :2]], dtype=bool)
    return _sorted(np.concatenate([rows, matched[earlier]]))


def interpolate_gaps(rows: np.ndarray, max_gap: int, smooth_frames: float | None = None) -> np.ndarray:
    """`rows` with each track's gaps of at most `max_gap` frames filled by linear interpolation, and with
    `smooth_frames`, every box of each track replaced by its Gaussian-process smoothed value."""
    rows = _rows(rows)
    out = []
    for tid in np.unique(rows[:, 1]):
        track = rows[rows[:, 1] == tid]
        track = track[np.argsort(track[:, 0], kind="stable")]
        frames = track[:, 0]
        gaps = np.diff(frames) - 1
        filled = [track]
        for i in np.flatnonzero((gaps > 0) & (gaps <= max_gap)):
            new = np.arange(frames[i] + 1, frames[i + 1])
            t = (new - frames[i]) / (frames[i + 1] - frames[i])
            boxes = track[i, 2:6] + t[:, None] * (track[i + 1, 2:6] - track[i, 2:6])
            filled.append(np.column_stack([new, np.full(len(new), tid), boxes]))
        track = np.concatenate(filled)
        track = track[np.argsort(track[:, 0], kind="stable")]
        if smooth_frames is not None and len(track) > 2:
            track[:, 2:6] = gaussian_smooth(track[:, 0], track[:, 2:6], smooth_frames)
        out.append(track)
    return _sorted(np.concatenate(out)) if out else rows


def gaussian_smooth(frames: np.ndarray, values: np.ndarray, length_scale: float) -> np.ndarray:
    """Posterior mean at `frames` of a Gaussian process (RBF kernel of `length_scale` frames, a white
    noise term fitted to the data) fitted to `values` (N, D) column by column."""
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, WhiteKernel

    x = np.asarray(frames, dtype=float).reshape(-1, 1)
    out = np.empty_like(values, dtype=float)
    for j in range(values.shape[1]):
        y = values[:, j].astype(float)
        scale = max(float(np.std(y)), 1e-6)
        kernel = RBF(length_scale=length_scale, length_scale_bounds="fixed") + WhiteKernel(
            noise_level=0.01, noise_level_bounds=(1e-6, 1.0)
        )
        gp = GaussianProcessRegressor(kernel=kernel, normalize_y=False)
        mean = float(np.mean(y))
        gp.fit(x, (y - mean) / scale)
        out[:, j] = gp.predict(x) * scale + mean
    return out


def post_process(rows: np.ndarray, matched: np.ndarray | None, settings: OfflineSettings) -> np.ndarray:
    """Backfill (when `settings.backfill` and `matched` is given), then gap interpolation."""
    rows = _rows(rows)
    if settings.backfill and matched is not None:
        rows = backfill(rows, matched)
    if settings.max_gap > 0 or settings.smooth_frames is not None:
        rows = interpolate_gaps(rows, settings.max_gap, settings.smooth_frames)
    return rows


def _rows(rows: np.ndarray) -> np.ndarray:
    rows = np.asarray(rows, dtype=float)
    if rows.size == 0:
        return np.zeros((0, 6))
    if rows.ndim != 2 or rows.shape[1] < 6:
        raise ValueError(f"track rows must be (N, 6) (frame, id, x, y, w, h), got shape {rows.shape}")
    return rows[:, :6]


def _sorted(rows: np.ndarray) -> np.ndarray:
    """Rows by frame, then track id."""
    return rows[np.lexsort((rows[:, 1], rows[:, 0]))]
