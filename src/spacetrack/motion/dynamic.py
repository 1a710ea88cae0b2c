"""Dynamic-target identification: which detector boxes are moving targets, which are static objects.

The paper matches the detector's positions with the fusion's moving regions "by the threshold". Here a box
is dynamic when a motion blob of the same frame overlaps it enough (relative to the smaller of the two)
and covers enough of the box, or when a blob's centroid lies close enough to the box centre (a small
target's blob may be offset by the smoothing). Static objects (parked satellites, stars) have no blob, so
they never reach the tracker; the coverage test keeps a large static box (a planet limb) static when a
small moving target crosses it.

Pair detections of frame t with the blobs of frame t: a fusion detector returns the blobs of frame
`mask_index`, which is `latency` frames behind the newest frame fed.
"""

from __future__ import annotations

import numpy as np

from spacetrack.data.layout import BOX
from spacetrack.motion.blobs import Blob, blob_boxes
from spacetrack.tracking.iou_matching import intersections, iou_matrix


def coverage(a_tlwh: np.ndarray, b_tlwh: np.ndarray) -> np.ndarray:
    """(N, M) fraction of box a's area inside box b, for boxes in tlwh pixels (0 for an empty box a)."""
    inter, area_a, _ = intersections(a_tlwh, b_tlwh)
    return np.divide(inter, area_a[:, None], out=np.zeros_like(inter), where=area_a[:, None] > 0)


def overlap_min_area(a_tlwh: np.ndarray, b_tlwh: np.ndarray) -> np.ndarray:
    """(N, M) intersection area over the smaller box's area, for boxes in tlwh pixels (0 for empty boxes).

    Intersection over the smaller box, not IoU: a motion blob is often much smaller or larger than the
    detector box of the same target, and should still count as the same thing.
    """
    inter, area_a, area_b = intersections(a_tlwh, b_tlwh)
    smaller = np.minimum(area_a[:, None], area_b[None, :])
    return np.divide(inter, smaller, out=np.zeros_like(inter), where=smaller > 0)


class DynamicFilter:
    """Marks detector boxes dynamic or static from the motion blobs of the same frame.

    Args:
        min_overlap: a box is dynamic if some blob's intersection with it, over the smaller of the two
            areas, is at least this (0-1) ...
        min_coverage: ... and the same blob's box covers at least this fraction of the box (0-1);
        max_distance: or if some blob's centroid lies within this many pixels of the box centre;
            0 turns the distance test off.
        min_share_of_best: a blob marks a box it passes the tests for only if its IoU with the box is at
            least this share (0-1) of its best IoU with any box it passes: a mover's blob that spills over
            a parked object the mover passes then marks the mover alone, while two movers that share one
            blob are both marked. 0: every box it passes (the paper's test).
    """

    def __init__(
        self,
        *,
        min_overlap: float = 0.3,
        min_coverage: float = 0.1,
        max_distance: float = 8.0,
        min_share_of_best: float = 0.0,
    ) -> None:
        if not 0 < min_overlap <= 1:
            raise ValueError(f"min_overlap must lie in (0, 1], got {min_overlap}")
        if not 0 <= min_coverage <= 1:
            raise ValueError(f"min_coverage must lie in [0, 1], got {min_coverage}")
        if max_distance < 0:
            raise ValueError(f"max_distance must be >= 0 pixels, got {max_distance}")
        self.min_overlap = min_overlap
        self.min_coverage = min_coverage
        if not 0 <= min_share_of_best <= 1:
            raise ValueError(f"min_share_of_best must lie in [0, 1], got {min_share_of_best}")
        self.max_distance = max_distance
        self.min_share_of_best = float(min_share_of_best)

    def __call__(self, boxes_tlwh: np.ndarray, blobs: list[Blob]) -> np.ndarray:
        """(N,) bool: True where box i (tlwh pixels) is a moving target."""
        boxes = np.asarray(boxes_tlwh, dtype=np.float64).reshape(-1, 4)
        if len(boxes) == 0 or not blobs:
            return np.zeros(len(boxes), dtype=bool)
        others = blob_boxes(blobs)
        overlapping = overlap_min_area(boxes, others) >= self.min_overlap
        passes = overlapping & (coverage(boxes, others) >= self.min_coverage)  # (N boxes, M blobs)
        if self.max_distance > 0:
            centres = boxes[:, :2] + boxes[:, 2:] / 2
            centroids = np.array([b.centroid for b in blobs])
            dist = np.linalg.norm(centres[:, None, :] - centroids[None, :, :], axis=2)
            passes |= dist <= self.max_distance
        if self.min_share_of_best > 0:
            iou = np.where(passes, iou_matrix(boxes, others), 0.0)
            passes &= iou >= self.min_share_of_best * iou.max(axis=0, keepdims=True)
        return passes.any(axis=1)

    def select(self, detections: np.ndarray, blobs: list[Blob]) -> np.ndarray:
        """The rows of a detection array (`tracking.io` layout, box `tlwh` at `data.layout.BOX`) that move."""
        return detections[self(detections[:, BOX], blobs)]


class DynamicHold:
    """Keeps feeding a track whose target the motion stage loses for a few frames (beyond the paper).

    The per-frame filter drops a box in every frame whose motion mask misses it, so a dim target that
    flickers in and out of the mask, or one that slows down, loses its detections and then its track.
    With `frames` > 0 a box the filter calls static still reaches the tracker when it overlaps (IoU >=
    `min_iou`) the box of a track output on the previous frame, for at most `frames` frames in a row
    per track; a dynamic box on the track ends the run. Tracks still start only from dynamic boxes, so a
    parked object never becomes one, and a target that stops for good is dropped after `frames` frames.
    `frames=0` is the paper's per-frame filter.
    """

    def __init__(self, *, frames: int = 0, min_iou: float = 0.5) -> None:
        if frames < 0:
            raise ValueError(f"dynamic_hold.frames must be >= 0, got {frames}")
        if not 0 < min_iou <= 1:
            raise ValueError(f"dynamic_hold.min_iou must lie in (0, 1], got {min_iou}")
        self.frames, self.min_iou = int(frames), float(min_iou)
        self.reset()

    def reset(self) -> None:
        """Forget every track (a new sequence)."""
        self._ids = np.zeros(0, dtype=np.int64)
        self._boxes = np.zeros((0, 4))
        self._held: dict[int, int] = {}  # track id -> frames in a row it was fed by held boxes

    def keep(self, boxes_tlwh: np.ndarray, dynamic: np.ndarray) -> np.ndarray:
        """(N,) bool: the boxes that reach the tracker this frame (the dynamic ones and the held ones)."""
        dynamic = np.asarray(dynamic, dtype=bool)
        if self.frames == 0 or len(self._ids) == 0 or dynamic.all():
            return dynamic.copy()
        iou = iou_matrix(boxes_tlwh, self._boxes)
        near = iou >= self.min_iou
        refreshed = near[dynamic].any(axis=0)  # tracks a dynamic box still feeds
        best = iou.argmax(axis=1)
        keep = dynamic.copy()
        held_tracks = set()
        for i in np.flatnonzero(~dynamic):
            j = best[i]
            track = int(self._ids[j])
            if near[i, j] and not refreshed[j] and self._held.get(track, 0) < self.frames:
                keep[i] = True
                held_tracks.add(track)
        for j, track in enumerate(self._ids.tolist()):
            if refreshed[j]:
                self._held[track] = 0
            elif track in held_tracks:
                self._held[track] = self._held.get(track, 0) + 1
        return keep

    def update(self, tracks: np.ndarray) -> None:
        """Remember the tracker's output of this frame: rows (track id, x, y, w, h)."""
        tracks = np.asarray(tracks, dtype=np.float64).reshape(-1, 5)
        self._ids, self._boxes = tracks[:, 0].astype(np.int64), tracks[:, 1:5]
        alive = set(self._ids.tolist())
        self._held = {k: v for k, v in self._held.items() if k in alive}
