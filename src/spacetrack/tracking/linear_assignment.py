"""Assignment of detections to tracks: one Hungarian step, and the matching cascade by track age."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

# Cost of a pair that must never match (gated out); any cost above the threshold is rejected anyway.
INFTY_COST = 1e5

# (track indices, detection indices) -> cost matrix (len(tracks), len(detections))
CostFunction = Callable[[list[int], list[int]], np.ndarray]
Matches = list[tuple[int, int]]


def min_cost_matching(
    cost_fn: CostFunction, max_distance: float, track_indices: Sequence[int], detection_indices: Sequence[int]
) -> tuple[Matches, list[int], list[int]]:
    """Hungarian assignment on `cost_fn`, rejecting pairs that cost more than `max_distance`.

    Returns (matches as (track, detection) pairs, unmatched tracks, unmatched detections). The
    unmatched lists keep the reference order: first those the assignment left out, in input order,
    then those whose assigned pair was rejected, in assignment order.
    """
    track_indices, detection_indices = list(track_indices), list(detection_indices)
    if not track_indices or not detection_indices:
        return [], track_indices, detection_indices
    cost = np.array(cost_fn(track_indices, detection_indices), dtype=float)
    cost[cost > max_distance] = max_distance + 1e-5
    rows, cols = linear_sum_assignment(cost)
    accepted = cost[rows, cols] <= max_distance
    assigned_rows = np.zeros(len(track_indices), bool)
    assigned_rows[rows] = True
    assigned_cols = np.zeros(len(detection_indices), bool)
    assigned_cols[cols] = True
    matches = [
        (track_indices[r], detection_indices[c]) for r, c in zip(rows[accepted], cols[accepted], strict=True)
    ]
    unmatched_tracks = [t for t, a in zip(track_indices, assigned_rows, strict=True) if not a]
    unmatched_tracks += [track_indices[r] for r in rows[~accepted]]
    unmatched_detections = [d for d, a in zip(detection_indices, assigned_cols, strict=True) if not a]
    unmatched_detections += [detection_indices[c] for c in cols[~accepted]]
    return matches, unmatched_tracks, unmatched_detections


def matching_cascade(
    cost_fn: CostFunction,
    max_distance: float,
    cascade_depth: int,
    track_indices: Sequence[int],
    time_since_update: Sequence[int],
    detection_indices: Sequence[int],
) -> tuple[Matches, list[int], list[int]]:
    """Match tracks seen 1 frame ago first, then 2 frames ago, ... up to `cascade_depth` frames.

    Recently seen tracks get first pick of the detections, so a long-lost track, whose predicted
    position is vague, cannot steal a detection from a track that is certain (the DeepSORT cascade).
    `time_since_update[i]` belongs to `track_indices[i]`. Returns as `min_cost_matching`; unmatched
    tracks in increasing index order.
    """
    unmatched_detections = list(detection_indices)
    age = dict(zip(track_indices, time_since_update, strict=True))
    matches: Matches = []
    for level in range(1, cascade_depth + 1):
        if not unmatched_detections:
            break
        tracks_l = [k for k in track_indices if age[k] == level]
        if not tracks_l:
            continue
        matches_l, _, unmatched_detections = min_cost_matching(
            cost_fn, max_distance, tracks_l, unmatched_detections
        )
        matches += matches_l
    matched = {k for k, _ in matches}
    unmatched_tracks = sorted(k for k in track_indices if k not in matched)
    return matches, unmatched_tracks, unmatched_detections
