"""Appearance metric (eq. 13): the smallest cosine distance between a detection and a track's gallery.

Each confirmed track keeps its last `nn_budget` appearance features (its gallery R_n). All galleries are
stacked into one matrix so that a whole cost matrix is one matrix product and one segmented minimum.
"""

from __future__ import annotations

import numpy as np


class NearestNeighborDistanceMetric:
    """Cosine nearest-neighbour distance to each track's gallery.

    Features are expected L2-normalised (`Detections.create` does it), so the cosine distance is
    1 - dot product. `max_cosine_distance` is the gate t(2) of eq. (14); `nn_budget` (None = unbounded)
    is how many of its latest features a track keeps.
    """

    def __init__(self, *, max_cosine_distance: float, nn_budget: int | None = None) -> None:
        self.matching_threshold = float(max_cosine_distance)
        self.budget = nn_budget
        self.samples: dict[int, np.ndarray] = {}
        self._stack = np.zeros((0, 0))
        self._slices: dict[int, tuple[int, int]] = {}

    def partial_fit(self, features: np.ndarray, targets: np.ndarray, active_targets: list[int]) -> None:
        """Append `features` (N, D) to the galleries of `targets` (N,); forget every track not active."""
        galleries = {k: [self.samples[k]] for k in active_targets if k in self.samples}
        for target in np.unique(targets):
            galleries.setdefault(int(target), []).append(features[targets == target])
        self.samples = {}
        for k in active_targets:
            if k in galleries:
                gallery = np.concatenate(galleries[k])
                self.samples[k] = gallery if self.budget is None else gallery[-self.budget :]
        self._restack()

    def _restack(self) -> None:
        sizes = [len(s) for s in self.samples.values()]
        ends = np.cumsum(sizes)
        self._slices = {k: (int(e - n), int(e)) for k, n, e in zip(self.samples, sizes, ends, strict=True)}
        self._stack = np.concatenate(list(self.samples.values())) if self.samples else np.zeros((0, 0))

    def distance(self, features: np.ndarray, targets: list[int]) -> np.ndarray:
        """(len(targets), N) matrix of eq. (13): min over each target's gallery of 1 - r_m . r_k."""
        features = np.asarray(features, dtype=float)
        if not len(targets) or not len(features):
            return np.zeros((len(targets), len(features)))
        spans = [self._slices[t] for t in targets]
        rows = np.concatenate([np.arange(a, b) for a, b in spans])
        starts = np.cumsum([0] + [b - a for a, b in spans[:-1]])
        distances = 1.0 - self._stack[rows] @ features.T
        return np.minimum.reduceat(distances, starts, axis=0)
