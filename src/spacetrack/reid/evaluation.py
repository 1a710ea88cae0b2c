"""Re-ID evaluation on held-out identities: retrieval (rank-1, mAP) and the cosine distances the tracker sees.

Distances are cosine distances 1 - a.b between L2-normalised features. Three views:
- retrieval: every crop queries all other crops of the held-out sequences; same-identity crops closer
  than `exclude_frames` frames to the query are left out of its gallery, as the next frame of the same
  target would be a trivial match;
- pairs: every same-identity pair, and every pair of different targets of the same sequence (the ones the
  tracker must keep apart);
- gallery (eq. 13): for each crop, the smallest distance to its own identity's crops of the previous
  `window` frames, and to every other target's crops of the same window, as a track's gallery gives it.
The tracker's gate `max_cosine_distance` (0.2 in DeepSORT, 0.1 in the paper's Table 2) works only if the
same-identity values fall below it and the different-identity ones do not.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np


def retrieval(features: np.ndarray, identity: np.ndarray, frame: np.ndarray, *, exclude_frames: int) -> dict:
    """Mean rank-1 accuracy and mean average precision over queries that keep a positive in their gallery."""
    dist = 1.0 - features @ features.T
    same = identity[:, None] == identity[None, :]
    near = np.abs(frame[:, None] - frame[None, :]) < exclude_frames
    valid = ~(same & near)
    np.fill_diagonal(valid, False)
    rank1, aps = [], []
    for q in range(len(features)):
        gallery = np.flatnonzero(valid[q])
        positive = same[q, gallery]
        if not positive.any():
            continue
        hits = positive[np.argsort(dist[q, gallery], kind="stable")]
        rank1.append(hits[0])
        found = np.cumsum(hits)
        aps.append(np.mean(found[hits] / (np.flatnonzero(hits) + 1)))
    if not aps:
        raise ValueError("no query has a same-identity crop in its gallery: too few frames per identity")
    return {"rank1": float(np.mean(rank1)), "mAP": float(np.mean(aps)), "queries": len(aps)}


def pair_distances(
    features: np.ndarray, identity: np.ndarray, sequence: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(same-identity pair distances, different-identity same-sequence pair distances), each pair once."""
    dist = 1.0 - features @ features.T
    upper = np.triu(np.ones(dist.shape, dtype=bool), k=1)
    same = identity[:, None] == identity[None, :]
    same_seq = sequence[:, None] == sequence[None, :]
    return dist[upper & same], dist[upper & ~same & same_seq]


def gallery_distances(
    features: np.ndarray, identity: np.ndarray, sequence: np.ndarray, frame: np.ndarray, *, window: int
) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (13) distances over galleries of the previous `window` frames: (min distance of each crop to its
    own identity's gallery, min distance of each crop to each other same-sequence identity's gallery)."""
    same_min, other_min = [], []
    for s in np.unique(sequence):
        rows = np.flatnonzero(sequence == s)
        dist = 1.0 - features[rows] @ features[rows].T
        ids, frames = identity[rows], frame[rows]
        gap = frames[:, None] - frames[None, :]
        in_window = (gap >= 1) & (gap <= window)
        for target in np.unique(ids):
            member = in_window & (ids[None, :] == target)
            masked = np.where(member, dist, np.inf).min(axis=1)
            has = member.any(axis=1)
            own = ids == target
            same_min.append(masked[has & own])
            other_min.append(masked[has & ~own])
    return np.concatenate(same_min), np.concatenate(other_min)


def fraction_below(values: np.ndarray, threshold: float) -> float:
    return float(np.mean(values < threshold)) if len(values) else float("nan")


def distance_metrics(
    same: np.ndarray, other: np.ndarray, thresholds: Sequence[float], prefix: str
) -> dict[str, float]:
    """`<prefix>same_below_<t>`, `<prefix>diff_below_<t>` fractions and the medians of both."""
    out = {f"{prefix}same_median": float(np.median(same)), f"{prefix}diff_median": float(np.median(other))}
    for t in thresholds:
        out[f"{prefix}same_below_{t:g}"] = fraction_below(same, t)
        out[f"{prefix}diff_below_{t:g}"] = fraction_below(other, t)
    return out


def evaluate_features(
    features: np.ndarray,
    identity: np.ndarray,
    sequence: np.ndarray,
    frame: np.ndarray,
    *,
    exclude_frames: int,
    window: int,
    thresholds: Sequence[float],
) -> tuple[dict[str, float], dict[str, np.ndarray]]:
    """(metrics, distance arrays for the plot) of held-out crops' features."""
    metrics = retrieval(features, identity, frame, exclude_frames=exclude_frames)
    same, other = pair_distances(features, identity, sequence)
    g_same, g_other = gallery_distances(features, identity, sequence, frame, window=window)
    metrics |= distance_metrics(same, other, thresholds, "pair_")
    metrics |= distance_metrics(g_same, g_other, thresholds, "gallery_")
    arrays = {"pair_same": same, "pair_diff": other, "gallery_same": g_same, "gallery_diff": g_other}
    return {k: float(v) for k, v in metrics.items()}, arrays


def plot_distances(
    arrays: dict[str, np.ndarray], thresholds: Sequence[float], path: str | Path, title: str = ""
) -> None:
    """Histograms of same- vs different-identity cosine distances (pairs; eq. 13 galleries) with the gates."""
    from matplotlib.figure import Figure

    from spacetrack.io import atomic_path

    fig = Figure(figsize=(11, 4))
    axes = fig.subplots(1, 2, sharex=True)
    bins = np.linspace(0, max(1.0, *(a.max() for a in arrays.values() if len(a))), 81)
    for ax, kind, label in zip(
        axes, ("pair", "gallery"), ("all pairs", "eq. 13 gallery minimum"), strict=True
    ):
        for part, colour in (("same", "tab:green"), ("diff", "tab:red")):
            values = arrays[f"{kind}_{part}"]
            name = "same identity" if part == "same" else "different targets, same sequence"
            ax.hist(
                values, bins=bins, density=True, alpha=0.55, color=colour, label=f"{name} (n={len(values)})"
            )
        lines = []
        for t in thresholds:
            ax.axvline(t, color="k", ls="--", lw=1)
            same, diff = (fraction_below(arrays[f"{kind}_{p}"], t) for p in ("same", "diff"))
            lines.append(f"below {t:g}: same {same:.1%}, different {diff:.2%}")
        ax.text(0.98, 0.6, "\n".join(lines), transform=ax.transAxes, ha="right", fontsize=8)
        ax.set(title=label, xlabel="cosine distance 1 - a.b", ylabel="density")
        ax.legend(fontsize=8, loc="upper right")
    fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=Path(path).suffix.lstrip(".") or "png", dpi=110)
