"""BoxMOT's trackers behind `DeepSort`'s `step` interface: the peers Table 4 sets beside our DeepSORT.

`conf/tracker/{bytetrack,ocsort,botsort,strongsort,deepocsort}.yaml` build a `PeerTracker`; the pipeline
then feeds it the same detections (cached or fresh) and, to the peers that match by appearance, our re-ID
features. BoxMOT is an optional extra (`make peers`); each peer runs with BoxMOT's own default settings
(its `create_tracker` on its built-in config). A peer never builds a re-ID network of its own (it would
download weights): our features go in with every detection, and a peer that asks for them gets an error
when there are none.

Beyond the peer itself, the two rules our pipeline applies around any tracker:
- dynamics: the track-level dynamic decision (`tracking.dynamic`) on the peer's output tracks. A track's
  evidence is gathered on the frames the peer reports it matched to a detection (BoxMOT says which), so
  it starts with the peer's first output of the track rather than with its first detection.
- output_box: "state", the peer's own box; "detection", the matched detection's box on frames with one.
"""

from __future__ import annotations

import logging
from typing import Any

import cv2
import numpy as np
import torch

from spacetrack.tracking.camera_motion import CameraMotion
from spacetrack.tracking.class_vote import UNKNOWN, ClassVotes
from spacetrack.tracking.deepsort import track_rows
from spacetrack.tracking.dynamic import MotionEvidence, TrackDynamics
from spacetrack.tracking.tracker import OUTPUT_BOXES

BOXMOT_VERSION = "25.0.0"  # the release this adapter is written against (the Makefile's BOXMOT pin)
PEERS = ("bytetrack", "ocsort", "botsort", "strongsort", "deepocsort")


class PeerUnavailableError(ImportError):
    """BoxMOT is missing or is another release than `BOXMOT_VERSION`."""


def load_boxmot() -> Any:
    """The `boxmot` module, checked to be release `BOXMOT_VERSION` (its tracker interface changes)."""
    try:
        import boxmot
    except ImportError as err:
        raise PeerUnavailableError(
            f"the peer trackers need BoxMOT, which is not installed: `make peers` installs boxmot=={BOXMOT_VERSION}"
        ) from err
    found = getattr(boxmot, "__version__", "unknown")
    if found != BOXMOT_VERSION:
        raise PeerUnavailableError(
            f"BoxMOT {found} is installed, but spacetrack.tracking.peers is written against BoxMOT "
            f"{BOXMOT_VERSION} (its tracker interface changes between releases): `make peers` installs it"
        )
    return boxmot


class _OncePerMessage(logging.Filter):
    """Let each distinct message through once: BoT-SORT warns on every frame whose ECC does not converge."""

    def __init__(self) -> None:
        super().__init__()
        self.seen: set[str] = set()

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        if message in self.seen:
            return False
        self.seen.add(message)
        return True


_ONCE = _OncePerMessage()


def _quiet_boxmot() -> None:
    """BoxMOT's logger at WARNING (it logs every tracker's settings at INFO), each message once."""
    logger = logging.getLogger("boxmot")
    logger.setLevel(logging.WARNING)
    if _ONCE not in logger.filters:
        logger.addFilter(_ONCE)


def create_peer(peer: str) -> Any:
    """BoxMOT's tracker `peer` (one of `PEERS`) with BoxMOT's default settings."""
    if peer not in PEERS:
        raise ValueError(f"tracker.peer must be one of {PEERS}, got {peer!r}")
    load_boxmot()
    from boxmot.trackers.factory import create_tracker
    from boxmot.trackers.specs import TrackerSpec

    _quiet_boxmot()  # after the imports: BoxMOT sets its logger up when they first load it
    return create_tracker(TrackerSpec(name=peer))


class PeerTracker:
    """One sequence tracked by BoxMOT's tracker `peer`, frame by frame, like `DeepSort.step`.

    peer: bytetrack | ocsort | botsort (with its own camera-motion compensation) | strongsort |
        deepocsort (the last three match by appearance: they need the detections' re-ID features).
    camera_motion: the scene shift for `dynamics`' motion evidence (`tracking.camera_motion`): false,
        true or auto. It does not move the peer's predictions (BoT-SORT compensates on its own).
    dynamics: decide per track what moves and output only the tracks that do; None outputs them all.
    output_box: "state" (the peer's box) or "detection" (the matched detection's box on frames with one).
    """

    min_confidence = 0.0  # BoxMOT applies its own detection thresholds

    def __init__(
        self,
        *,
        peer: str,
        camera_motion: bool | str = False,
        dynamics: TrackDynamics | None = None,
        output_box: str = "state",
    ) -> None:
        if output_box not in OUTPUT_BOXES:
            raise ValueError(f"tracker.output_box must be one of {OUTPUT_BOXES}, got {output_box!r}")
        self.peer = peer
        self.tracker = create_peer(peer)
        self.requirements = self.tracker.requirements
        self.camera = CameraMotion(camera_motion if dynamics is not None else False)
        self.dynamics = dynamics
        self.output_box = output_box
        self.evidence: dict[int, MotionEvidence] = {}
        self._static = np.zeros((0, 5))
        self._matched = np.zeros((0, 5))
        self.votes = ClassVotes()
        self._output_classes = np.zeros((0, 2), dtype=int)
        self._frame = 0

    @property
    def needs_images(self) -> bool:
        """Whether `step` uses the frame (the peer's camera-motion compensation, or `camera_motion`)."""
        return bool(self.requirements.frame) or self.camera.mode is not False

    def step(
        self,
        tlwh: np.ndarray,
        confidence: np.ndarray,
        feature: np.ndarray | None = None,
        *,
        dynamic: np.ndarray | None = None,
        image: np.ndarray | None = None,
        classes: np.ndarray | None = None,
    ) -> np.ndarray:
        """Track one frame: boxes `tlwh` (N, 4) pixels, confidences (N,) in [0, 1], re-ID features (N, D).

        dynamic: (N,) bool, whether a motion blob matched each box (the evidence of `dynamics`).
        image: the frame, (H, W, 3) RGB or (H, W) grey uint8; the peers that compensate camera motion
            need it.
        classes: (N,) the detector's class index of each box, for each track's class vote (None: unknown).
        Returns the frame's output tracks as rows (track id, x, y, w, h), box `tlwh`; ids start at 1.
        """
        from boxmot.structures import Boxes, Detections

        self._frame += 1
        tlwh = np.asarray(tlwh, dtype=float).reshape(-1, 4)
        kept = np.flatnonzero((tlwh[:, 2] > 0) & (tlwh[:, 3] > 0))  # BoxMOT refuses empty boxes
        xyxy = np.column_stack([tlwh[kept, :2], tlwh[kept, :2] + tlwh[kept, 2:]])
        scores = np.clip(np.asarray(confidence, dtype=float).reshape(-1)[kept], 0.0, 1.0)
        detections = Detections(
            geometry=Boxes(torch.from_numpy(xyxy.astype(np.float32))),
            scores=torch.from_numpy(scores.astype(np.float32)),
            class_ids=torch.zeros(len(kept), dtype=torch.int64),
            sample_id=f"frame{self._frame}",
            embeddings=self._embeddings(feature, kept),
        )
        shift_image = image if self.camera.mode is not False else None
        self.camera.update(shift_image)
        out = self.tracker.update(detections, self._frame_bgr(image))
        ids = out.track_ids.numpy().astype(int) + 1
        boxes = out.geometry.values.numpy().astype(float)
        boxes[:, 2:] -= boxes[:, :2]
        matched = out.detection_indices.numpy().astype(int)
        source = np.where(matched >= 0, kept[np.maximum(matched, 0)], -1)  # index into this frame's input
        if self.output_box == "detection":
            boxes[source >= 0] = tlwh[source[source >= 0]]
        rows = track_rows(list(zip(ids, boxes, strict=True)))
        self._matched = rows[source >= 0]
        frame_classes = self._vote(ids, source, confidence, classes)
        moving = np.ones(len(rows), bool)
        if self.dynamics is not None:
            size = None if image is None else (image.shape[1], image.shape[0])
            moving = self._observe(ids, source, tlwh, dynamic, size)
            self._static = rows[~moving]
        self._output_classes = frame_classes[moving]
        return rows[moving]

    @property
    def class_votes(self) -> ClassVotes:
        """Each track's class, voted over its matched detections (every track of the sequence so far)."""
        return self.votes

    def output_classes(self) -> np.ndarray:
        """(T, 2) int rows aligned with the last `step`'s output: the class of the detection each track
        matched on that frame (-1 when it had none) and the track's voted class so far."""
        return self._output_classes

    def _vote(
        self, ids: np.ndarray, source: np.ndarray, confidence: np.ndarray, classes: np.ndarray | None
    ) -> np.ndarray:
        """Count this frame's matched detections in their tracks' class votes; (T, 2) `output_classes` rows."""
        confidence = np.asarray(confidence, dtype=float).reshape(-1)
        named = np.full(len(confidence), UNKNOWN) if classes is None else np.asarray(classes).astype(int)
        own = (
            np.where(source >= 0, named[np.maximum(source, 0)], UNKNOWN)
            if len(named)
            else np.full(len(ids), UNKNOWN)
        )
        for track_id, d, k in zip(ids, source, own, strict=True):
            if d >= 0:
                self.votes.add(int(track_id), int(k), confidence[d])
        return np.array(
            [(k, self.votes.winner(int(i))[0]) for i, k in zip(ids, own, strict=True)], dtype=int
        ).reshape(-1, 2)

    def static_tracks(self) -> np.ndarray:
        """Rows (track id, x, y, w, h) of this frame's tracks `dynamics` holds static (kept, not output)."""
        return self._static

    def matched_tracks(self) -> np.ndarray:
        """Rows (track id, x, y, w, h) of this frame's tracks matched to a detection, output or not."""
        return self._matched

    def _embeddings(self, feature: np.ndarray | None, kept: np.ndarray) -> torch.Tensor | None:
        if not self.requirements.embeddings:
            return None
        feature = None if feature is None else np.asarray(feature, dtype=np.float32)
        if feature is None or feature.ndim != 2 or feature.shape[1] == 0:
            raise ValueError(
                f"tracker={self.peer} matches by appearance, but the detections carry no re-ID features "
                "(reid.weights=none?): give it re-ID weights, or use tracker=bytetrack or tracker=ocsort"
            )
        return torch.from_numpy(np.ascontiguousarray(feature[kept]))

    def _frame_bgr(self, image: np.ndarray | None) -> np.ndarray | None:
        """The frame as BoxMOT takes it (HWC BGR uint8) when the peer uses it, else None."""
        if not self.requirements.frame:
            return None
        if image is None:
            raise ValueError(f"tracker={self.peer} compensates camera motion and needs each frame's image")
        code = cv2.COLOR_GRAY2BGR if image.ndim == 2 else cv2.COLOR_RGB2BGR
        return cv2.cvtColor(image, code)

    def _observe(
        self,
        ids: np.ndarray,
        source: np.ndarray,
        tlwh: np.ndarray,
        dynamic: np.ndarray | None,
        frame_size: tuple[int, int] | None,
    ) -> np.ndarray:
        """Add the matched detections to their tracks' motion evidence; (T,) bool, the tracks that move."""
        flags = np.ones(len(tlwh), bool) if dynamic is None else np.asarray(dynamic, bool).reshape(-1)
        for track_id, d in zip(ids, source, strict=True):
            evidence = self.evidence.setdefault(int(track_id), self.dynamics.new_evidence())
            if d >= 0:
                self.dynamics.observe(
                    evidence,
                    tlwh[d],
                    self.camera.offset,
                    bool(flags[d]),
                    camera_moving=self.camera.moving,
                    frame_size=frame_size,
                )
        return np.array([self.evidence[int(i)].dynamic for i in ids], dtype=bool)
