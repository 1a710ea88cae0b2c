"""Track-level dynamic decision (beyond the paper): is a track a moving target, judged over its life?

The paper decides per frame: a detector box reaches the tracker only when a motion blob of the same frame
matches it. That drops a moving target in every frame its mask misses (dim targets, targets that stop)
and lets a parked object through whenever the masks flicker on it. Here every box reaches the tracker,
each carrying its per-frame blob flag, and each track gathers two kinds of evidence:

- blob evidence: the share of its last `window` hits whose box a blob matched (the paper's threshold
  match, `motion.dynamic.DynamicFilter`), counted once the track has `min_blob_hits` of them;
- trajectory evidence: how far the track's box centre has moved *in scene coordinates* (the image
  position minus the camera's scene shift, `motion.compensation.SceneShift`) since its first hit. A parked
  object that only drifts with a slewing camera stays put there; a dim mover whose masks are thin
  travels on.

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
    """One track's evidence: blob flags of its last hits, its centres in scene coordinates (pixels)."""

    def __init__(self, window: int) -> None:
        self.flags: deque[bool] = deque(maxlen=window)
        self.centres: deque[np.ndarray] = deque(maxlen=window)
        self.anchor: np.ndarray | None = None
        self.dynamic = False


class TrackDynamics:
    """The thresholds of the track-level decision (`conf/track.yaml`, `dynamic_track`).

    window: hits (frames with a matched box) over which the blob share is taken and the current position
        is smoothed (median of the last `window` centres, so a box cut short for a frame or two by an
        occluder does not count as motion); >= 1.
    min_blob_ratio: a track is dynamic when at least this share (0-1) of its last `window` hits had a
        matching blob ...
    min_blob_hits: ... and at least this many of them did (>= 1);
    min_displacement: or when its smoothed centre lies this many pixels or more from its first centre,
        both in scene coordinates (> 0) ...
    min_displacement_height: ... and at least this many box heights away (>= 0): a large object's box
        centre wanders more with its outline than a small one's.
    blobs_when_camera_moves: whether blob evidence still counts once the camera has been found moving.
    """

    def __init__(
        self,
        *,
        window: int = 5,
        min_blob_ratio: float = 0.5,
        min_blob_hits: int = 2,
        min_displacement: float = 6.0,
        min_displacement_height: float = 0.25,
        blobs_when_camera_moves: bool = False,
    ) -> None:
        checks = {
            "window": (window, window >= 1, ">= 1"),
            "min_blob_ratio": (min_blob_ratio, 0.0 <= min_blob_ratio <= 1.0, "in [0, 1]"),
            "min_blob_hits": (min_blob_hits, min_blob_hits >= 1, ">= 1"),
            "min_displacement": (min_displacement, min_displacement > 0, "> 0 pixels"),
            "min_displacement_height": (min_displacement_height, min_displacement_height >= 0, ">= 0"),
        }
        for key, (value, ok, expected) in checks.items():
            if not ok:
                raise ValueError(f"dynamic_track.{key} must be {expected}, got {value}")
        self.window = int(window)
        self.min_blob_ratio = float(min_blob_ratio)
        self.min_blob_hits = int(min_blob_hits)
        self.min_displacement = float(min_displacement)
        self.min_displacement_height = float(min_displacement_height)
        self.blobs_when_camera_moves = bool(blobs_when_camera_moves)

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
    ) -> None:
        """Add one hit: the matched box `tlwh` (image pixels), the frame's scene `offset` (x, y pixels from
        the first frame) and whether a blob matched the box; latch `evidence.dynamic` once it holds.
        camera_moving: the camera has been found moving (blobs then count only with
        `blobs_when_camera_moves`)."""
        tlwh = np.asarray(tlwh, dtype=float)
        centre = tlwh[:2] + tlwh[2:] / 2 - np.asarray(offset, dtype=float)
        if evidence.anchor is None:
            evidence.anchor = centre
        evidence.flags.append(bool(blob))
        evidence.centres.append(centre)
        if evidence.dynamic:
            return
        hits = sum(evidence.flags)
        trust_blobs = self.blobs_when_camera_moves or not camera_moving
        by_blobs = (
            trust_blobs and hits >= self.min_blob_hits and hits >= self.min_blob_ratio * len(evidence.flags)
        )
        moved = float(np.linalg.norm(np.median(np.array(evidence.centres), axis=0) - evidence.anchor))
        by_trajectory = moved >= max(self.min_displacement, self.min_displacement_height * tlwh[3])
        evidence.dynamic = by_blobs or by_trajectory
