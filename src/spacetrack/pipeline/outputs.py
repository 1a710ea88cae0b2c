"""What the pipeline writes per sequence: the annotated frames of its MP4 (MOT files: `tracking.io`)."""

from __future__ import annotations

from collections import deque

import numpy as np

from spacetrack.viz.draw import draw_boxes, draw_text, draw_trails

TRACK_COLOR, STATIC_COLOR = (255, 40, 40), (60, 220, 60)


class Annotator:
    """Draws a frame's tracks (red boxes, ids, class names when given, and the last `trail_length` centres
    of each) and the detections the motion stage called static (green, labelled "static"), with an info
    line on top."""

    def __init__(self, *, trail_length: int = 40) -> None:
        self.trail_length = trail_length
        self.trails: dict[int, deque] = {}

    def __call__(
        self,
        rgb: np.ndarray,
        tracks: np.ndarray,
        static_tlwh: np.ndarray,
        info: str = "",
        *,
        names: list[str] | None = None,
    ) -> np.ndarray:
        """tracks: (M, 5) rows `id, x, y, w, h` (tlwh pixels); static_tlwh: (K, 4); names: (M,) each track's
        class name, written after its id."""
        for track_id, x, y, w, h in tracks:
            trail = self.trails.setdefault(int(track_id), deque(maxlen=self.trail_length))
            trail.append((x + w / 2, y + h / 2))
        shown = {int(t): list(self.trails[int(t)]) for t in tracks[:, 0]}
        out = draw_trails(rgb, shown, color=TRACK_COLOR)
        out = draw_boxes(out, static_tlwh, labels=["static"] * len(static_tlwh), color=STATIC_COLOR)
        out = draw_boxes(
            out, tracks[:, 1:5], ids=tracks[:, 0].astype(int).tolist(), labels=names, color=TRACK_COLOR
        )
        if info:
            draw_text(out, info, (4, 14), (255, 255, 255))
        return out
