"""Track-level dynamic decision (beyond the paper): is a track a moving target, judged over its life?

The paper decides per frame: a detector box reaches the tracker only when a motion blob of the same frame
matches it. That drops a moving target in every frame its mask misses (dim targets, targets that stop)
and lets a parked object through whenever the masks flicker on it. Here every box reaches the tracker,
each carrying its per-frame blob flag, and each track gathers two kinds of evidence:

- blob evidence: the share of its last `window` hits whose box a blob matched (the paper's threshold
  match, `motion.dynamic.DynamicFilter`), counted once the track has `min_blob_hits` of them;
- trajectory evidence: how far the track's box has moved *in scene coordinates* (the image position
  minus the camera's scene shift, `motion.compensation.SceneShift`) since its first hit. A parked
  object that only drifts with a slewing camera stays put there; a dim mover whose masks are thin
  travels on. The box counts as moved along an axis only by the shift its two opposite edges share: a
  mover passing in front of a parked object cuts the parked box down from one side, which moves its
  centre but moves its edges apart or together, not the same way. An edge on the image border says
  nothing (a target coming into view grows from the border): there the other edge's shift counts.

Under a moving camera the masks depend on how well the motion stage compensates the slew, and they
light up on parked objects while it has not caught up; once the tracker has found the camera moving
(`tracking.camera_motion`), blob evidence no longer makes a track dynamic unless `blobs_when_camera_moves`
says so, and the trajectory alone decides.

The decision latches: a track found dynamic stays dynamic when its target stops (the ground truth keeps a
stopped target's rows). Tracks not (yet) dynamic stay in the tracker, so a parked object keeps one
track instead of seeding a new one every frame, but they are never output.
"""

from __future__ import annotations

from collections import deque

import numpy as np


class MotionEvidence:
    """One track's evidence: blob flags of its last hits, its boxes' edges (x1, y1, x2, y2) in scene
    coordinates (pixels), and those of its first hit (`anchor`)."""

    def __init__(self, window: int) -> None:
        self.flags: deque[bool] = deque(maxlen=window)
        self.edges: deque[np.ndarray] = deque(maxlen=window)
        self.anchor: np.ndarray | None = None
        self.anchor_free = np.ones(4, dtype=bool)  # the anchor's edges that are off the image border
        self.anchor_offset = np.zeros(2)  # the scene offset (x, y pixels) at the first hit
        self.dynamic = False


def shared_shift(anchor: np.ndarray, edges: np.ndarray, free: np.ndarray | None = None) -> float:
    """Pixels a box with edges `edges` (x1, y1, x2, y2) moved from `anchor`: along each axis the shift its
    two opposite edges share (the smaller of the two when they move the same way, else 0).

    free: (4,) bool, the edges that may be trusted (off the image border); along an axis with one free
    edge that edge's shift counts, with none the axis counts 0. None: all four.
    """
    delta = (np.asarray(edges, dtype=float) - anchor).reshape(2, 2)  # rows: (x1, y1), (x2, y2)
    free = np.ones((2, 2), bool) if free is None else np.asarray(free, bool).reshape(2, 2)
    same_way = np.sign(delta[0]) == np.sign(delta[1])
    shared = np.where(same_way, np.sign(delta[0]) * np.abs(delta).min(axis=0), 0.0)
    one_free = free[0] != free[1]
    shared = np.where(one_free, np.where(free[0], delta[0], delta[1]), shared)
    shared = np.where(free.any(axis=0), shared, 0.0)
    return float(np.linalg.norm(shared))


def free_edges(tlwh: np.ndarray, frame_size: tuple[int, int] | None, margin: float = 1.0) -> np.ndarray:
    """(4,) bool: which edges (x1, y1, x2, y2) of an image box `tlwh` lie more than `margin` pixels inside
    a frame of `frame_size` (width, height); all of them when the size is not known."""
    if frame_size is None:
        return np.ones(4, dtype=bool)
    x1, y1, w, h = np.asarray(tlwh, dtype=float)
    width, height = frame_size
    return np.array([x1 > margin, y1 > margin, x1 + w < width - margin, y1 + h < height - margin])


class TrackDynamics:
    """The thresholds of the track-level decision (`conf/track.yaml`, `dynamic_track`).

    window: hits (frames with a matched box) over which the blob share is taken and the current position
        is smoothed (median of the last `window` boxes' edges, so a box cut short for a frame or two by an
        occluder does not count as motion); >= 1.
    min_blob_ratio: a track is dynamic when at least this share (0-1) of its last `window` hits had a
        matching blob ...
    min_blob_hits: ... and at least this many of them did (>= 1);
    min_displacement: or when its smoothed box has moved this many pixels or more from its first box
        (`shared_shift`), both in scene coordinates (> 0) ...
    min_displacement_height: ... and at least this many box heights away (>= 0): a large object's box
        centre wanders more with its outline than a small one's ...
    min_displacement_camera: ... and at least this share (>= 0) of the camera's own shift since the first
        hit: the shift is estimated frame by frame and its error grows with it, so under a long slew a
        parked object would otherwise drift away from its first position in scene coordinates.
    blobs_when_camera_moves: whether blob evidence still counts once the camera has been found moving.
    min_share_of_best: the blob test of this mode (`motion.DynamicFilter(min_share_of_best=...)`, which
        the pipeline builds from it): a blob is evidence for a box only if its IoU with the box is at least
        this share (0-1) of its best IoU with any box, so a mover's blob that spills over a parked object
        it passes is not evidence for the parked object.
    """

    def __init__(
        self,
        *,
        window: int = 5,
        min_blob_ratio: float = 0.5,
        min_blob_hits: int = 2,
        min_displacement: float = 6.0,
        min_displacement_height: float = 0.1,
        min_displacement_camera: float = 0.1,
        blobs_when_camera_moves: bool = False,
        min_share_of_best: float = 0.5,
    ) -> None:
        checks = {
            "window": (window, window >= 1, ">= 1"),
            "min_blob_ratio": (min_blob_ratio, 0.0 <= min_blob_ratio <= 1.0, "in [0, 1]"),
            "min_blob_hits": (min_blob_hits, min_blob_hits >= 1, ">= 1"),
            "min_displacement": (min_displacement, min_displacement > 0, "> 0 pixels"),
            "min_displacement_height": (min_displacement_height, min_displacement_height >= 0, ">= 0"),
            "min_displacement_camera": (min_displacement_camera, min_displacement_camera >= 0, ">= 0"),
            "min_share_of_best": (min_share_of_best, 0.0 <= min_share_of_best <= 1.0, "in [0, 1]"),
        }
        for key, (value, ok, expected) in checks.items():
            if not ok:
                raise ValueError(f"dynamic_track.{key} must be {expected}, got {value}")
        self.window = int(window)
        self.min_blob_ratio = float(min_blob_ratio)
        self.min_blob_hits = int(min_blob_hits)
        self.min_displacement = float(min_displacement)
        self.min_displacement_height = float(min_displacement_height)
        self.min_displacement_camera = float(min_displacement_camera)
        self.blobs_when_camera_moves = bool(blobs_when_camera_moves)
        self.min_share_of_best = float(min_share_of_best)

    def new_evidence(self) -> MotionEvidence:
        return MotionEvidence(self.window)

    def observe(
        self,
        evidence: MotionEvidence,
        tlwh: np.ndarray,
        offset: np.ndarray,
        blob: bool,
        *,
        camera_moving: bool = False,
        frame_size: tuple[int, int] | None = None,
    ) -> None:
        """Add one hit: the matched box `tlwh` (image pixels), the frame's scene `offset` (x, y pixels from
        the first frame) and whether a blob matched the box; latch `evidence.dynamic` once it holds.
        camera_moving: the camera has been found moving (blobs then count only with
        `blobs_when_camera_moves`); frame_size: the image's (width, height), so that edges on its border
        do not count (None: every edge counts)."""
        tlwh = np.asarray(tlwh, dtype=float)
        corner = tlwh[:2] - np.asarray(offset, dtype=float)
        edges = np.concatenate([corner, corner + tlwh[2:]])
        free = free_edges(tlwh, frame_size)
        offset = np.asarray(offset, dtype=float)
        if evidence.anchor is None:
            evidence.anchor, evidence.anchor_free, evidence.anchor_offset = edges, free, offset
        evidence.flags.append(bool(blob))
        evidence.edges.append(edges)
        if evidence.dynamic:
            return
        hits = sum(evidence.flags)
        trust_blobs = self.blobs_when_camera_moves or not camera_moving
        by_blobs = (
            trust_blobs and hits >= self.min_blob_hits and hits >= self.min_blob_ratio * len(evidence.flags)
        )
        now = np.median(np.array(evidence.edges), axis=0)
        moved = shared_shift(evidence.anchor, now, evidence.anchor_free & free)
        camera_shift = float(np.linalg.norm(offset - evidence.anchor_offset))
        needed = max(
            self.min_displacement,
            self.min_displacement_height * tlwh[3],
            self.min_displacement_camera * camera_shift,
        )
        by_trajectory = moved >= needed
        evidence.dynamic = by_blobs or by_trajectory
