"""Each track's class, voted over its matched detections: the detector names a box frame by frame, and a
target it names two ways (a rocket body seen end-on is a disc, like debris) gets the name most of its
boxes carry, weighted by their scores."""

from __future__ import annotations

from collections import defaultdict

UNKNOWN = -1  # the class of a box or track no detector named


class ClassVotes:
    """Score-weighted class votes per track id, over the whole life of every track (deleted ones too)."""

    def __init__(self) -> None:
        self._votes: dict[int, dict[int, float]] = defaultdict(lambda: defaultdict(float))

    def add(self, track_id: int, class_index: int, score: float) -> None:
        """Count one matched detection of class `class_index` (UNKNOWN: nothing to count) scoring `score`."""
        if class_index != UNKNOWN:
            self._votes[int(track_id)][int(class_index)] += max(float(score), 0.0)

    def winner(self, track_id: int) -> tuple[int, float]:
        """(class, its share of the track's summed score) so far; (UNKNOWN, 0.0) for a track with no vote.
        Ties go to the lower class index."""
        votes = self._votes.get(int(track_id))
        total = sum(votes.values()) if votes else 0.0
        if not votes or total <= 0:
            return UNKNOWN, 0.0
        best = min(votes, key=lambda k: (-votes[k], k))
        return best, votes[best] / total

    def table(self) -> dict[int, tuple[int, float]]:
        """{track id: (class, share)} of every track that has a vote."""
        return {k: self.winner(k) for k in sorted(self._votes)}
