"""Appearance metric (eq. 13): the smallest cosine distance between a detection and a track's gallery.

Each confirmed track keeps its last `nn_budget` appearance features (its gallery R_n). All galleries
live in one preallocated bank (slot per track x gallery row x feature) used as ring buffers, so a whole
cost matrix is one matrix product and one masked minimum, and adding a frame's features copies nothing
else. The minimum depends neither on the order within a gallery nor on repeats, so overwriting the
oldest row in place gives the same distances as keeping the latest `nn_budget` in order, and the rows a
gallery has not filled yet hold copies of its first feature instead of needing a mask.
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
        if nn_budget is not None and nn_budget < 1:
            raise ValueError(f"nn_budget must be a positive number of features or None, got {nn_budget}")
        self.matching_threshold = float(max_cosine_distance)
        self.budget = nn_budget
        self._slot: dict[int, int] = {}  # track id -> slot in the bank
        self._bank = np.zeros((0, 0, 0))  # (slots, gallery capacity, D)
        self._count = np.zeros(0, dtype=int)  # features ever added to each slot's gallery

    def samples(self, target: int) -> np.ndarray:
        """The gallery of track `target`, (n, D), in storage order."""
        slot = self._slot[target]
        return self._bank[slot, : min(self._count[slot], self._bank.shape[1])]

    def partial_fit(self, features: np.ndarray, targets: np.ndarray, active_targets: list[int]) -> None:
        """Append `features` (N, D) to the galleries of `targets` (N,); forget every track not active."""
        active = set(active_targets)
        for target in [t for t in self._slot if t not in active]:
            self._count[self._slot.pop(target)] = 0
        features = np.asarray(features, dtype=float)
        targets = np.asarray(targets, dtype=int)
        if not len(targets):
            return
        order = np.argsort(targets, kind="stable")  # keeps each target's features in time order
        features, targets = features[order], targets[order]
        unique, first, inverse = np.unique(targets, return_index=True, return_inverse=True)
        self._reserve(features.shape[1], len(self._slot.keys() | set(unique.tolist())))
        slots = np.array(
            [self._slot.get(t) if t in self._slot else self._new_slot(t) for t in unique.tolist()]
        )
        rank = np.arange(len(targets)) - first[inverse]  # index of each feature within its target's batch
        for k in range(int(rank.max()) + 1):
            self._write(slots[inverse[rank == k]], features[rank == k])

    def _new_slot(self, target: int) -> int:
        used = np.zeros(len(self._bank), bool)
        used[list(self._slot.values())] = True
        slot = self._slot[target] = int(np.flatnonzero(~used)[0])
        return slot

    def _reserve(self, dim: int, num_slots: int) -> None:
        """Grow the bank (doubling) to hold `num_slots` galleries of `dim`-dim features."""
        slots, capacity, _ = self._bank.shape
        if not capacity:
            capacity = self.budget or 16
        if num_slots > slots or not self._bank.size:
            self._resize(max(num_slots, 2 * slots, 8), capacity, dim)

    def _resize(self, slots: int, capacity: int, dim: int) -> None:
        bank = np.zeros((slots, capacity, dim))
        old_slots, old_capacity, _ = self._bank.shape
        if self._bank.size:
            bank[:old_slots, :old_capacity] = self._bank
            bank[:old_slots, old_capacity:] = self._bank[:, :1]  # unfilled rows repeat the first feature
        count = np.zeros(slots, dtype=int)
        count[:old_slots] = self._count
        self._bank, self._count = bank, count

    def _write(self, slots: np.ndarray, features: np.ndarray) -> None:
        """Add one feature (row of `features`) to each of the distinct galleries `slots`."""
        capacity = self._bank.shape[1]
        if self.budget is None and self._count[slots].max() >= capacity:
            # Unbounded galleries: make room by doubling the capacity of every slot.
            self._resize(len(self._bank), 2 * capacity, self._bank.shape[2])
            capacity *= 2
        fresh = self._count[slots] == 0
        self._bank[slots[fresh]] = features[fresh][:, None, :]  # unfilled rows repeat the first feature
        self._bank[slots, self._count[slots] % capacity] = features
        self._count[slots] += 1

    def distance(
        self, features: np.ndarray, targets: list[int], admissible: np.ndarray | None = None
    ) -> np.ndarray:
        """(len(targets), N) matrix of eq. (13): min over each target's gallery of 1 - r_m . r_k.

        `admissible` (len(targets), N) bool limits the work to the pairs that can still match (those
        inside the motion gate); the others come back as inf. Each track is compared with only its
        own admissible detections, packed into a (tracks, k, D) batch, so the cost grows with the
        number of admissible pairs rather than tracks x detections.
        """
        features = np.asarray(features, dtype=float)
        out = np.full((len(targets), len(features)), np.inf)
        if admissible is None:
            admissible = np.ones(out.shape, bool)
        rows, cols = np.nonzero(admissible)
        if not len(rows):
            return out
        per_row = np.bincount(rows, minlength=len(targets))
        used = np.flatnonzero(per_row)
        position = np.arange(len(rows)) - np.repeat(np.cumsum(per_row) - per_row, per_row)
        batch_row = np.searchsorted(used, rows)
        packed = np.zeros((len(used), int(per_row.max()), features.shape[1]))
        packed[batch_row, position] = features[cols]
        slots = np.array([self._slot[targets[i]] for i in used])
        # Rows past the fullest gallery involved hold only repeats: leave them out of the product.
        filled = min(self._bank.shape[1], int(self._count[slots].max()))
        similarity = np.matmul(self._bank[slots, :filled], packed.transpose(0, 2, 1)).max(axis=1)
        out[rows, cols] = 1.0 - similarity[batch_row, position]
        return out
