"""Boxes, identities and trajectories drawn on RGB frames (for contact sheets and annotated clips).

Colours are RGB triples because frames are RGB in memory; OpenCV draws the triple in the array's own
channel order, so no conversion is needed here.
"""

from __future__ import annotations

import colorsys
from collections.abc import Mapping, Sequence

import cv2
import numpy as np

Color = tuple[int, int, int]

FONT = cv2.FONT_HERSHEY_SIMPLEX
FONT_SCALE = 0.4
# The golden-ratio step spreads consecutive ids far apart around the hue circle.
_GOLDEN = 0.618033988749895


def id_color(track_id: int) -> Color:
    """A bright RGB colour that is the same for an id in every frame and differs between nearby ids."""
    hue = (int(track_id) * _GOLDEN) % 1.0
    r, g, b = colorsys.hsv_to_rgb(hue, 0.85, 1.0)
    return (round(r * 255), round(g * 255), round(b * 255))


def check_rgb(image: np.ndarray, what: str = "image") -> None:
    """Raise ValueError unless `image` is an RGB uint8 array of shape (H, W, 3)."""
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"{what} must be RGB uint8 of shape (H, W, 3), got {image.dtype} {image.shape}")


def draw_text(image: np.ndarray, text: str, org: tuple[int, int], color: Color) -> None:
    """Write `text` in place with its bottom-left corner at `org` (x, y pixels) on a dark backing strip."""
    (w, h), baseline = cv2.getTextSize(text, FONT, FONT_SCALE, 1)
    x, y = org
    cv2.rectangle(image, (x, y - h - 1), (x + w, y + baseline - 1), (0, 0, 0), cv2.FILLED)
    cv2.putText(image, text, (x, y), FONT, FONT_SCALE, color, 1, cv2.LINE_AA)


def draw_boxes(
    rgb: np.ndarray,
    boxes_tlwh: np.ndarray | Sequence[Sequence[float]],
    *,
    labels: Sequence[str] | None = None,
    ids: Sequence[int] | None = None,
    color: Color = (255, 0, 0),
    color_by_id: bool = False,
    thickness: int = 1,
) -> np.ndarray:
    """A copy of `rgb` with one rectangle per box and its label and/or id written above it.

    `boxes_tlwh` is (N, 4) in pixels: top-left x, y, width, height. The outline lies on the box's
    outermost pixels, columns round(x) .. round(x+w)-1 and rows round(y) .. round(y+h)-1, so it frames
    a tight integer box exactly. With `color_by_id`, each box takes `id_color(id)` instead of `color`.
    """
    check_rgb(rgb, "frame")
    boxes = np.asarray(boxes_tlwh, dtype=np.float64)
    if boxes.size == 0:
        boxes = boxes.reshape(0, 4)
    if boxes.ndim != 2 or boxes.shape[1] != 4:
        raise ValueError(f"boxes_tlwh must have shape (N, 4), got {boxes.shape}")
    for name, values in (("labels", labels), ("ids", ids)):
        if values is not None and len(values) != len(boxes):
            raise ValueError(f"{name} has {len(values)} entries for {len(boxes)} boxes")
    if color_by_id and ids is None:
        raise ValueError("color_by_id needs ids")
    out = np.ascontiguousarray(rgb).copy()
    for i, (x, y, w, h) in enumerate(boxes):
        box_color = id_color(ids[i]) if color_by_id else color
        x1, y1 = round(x), round(y)
        x2, y2 = round(x + w) - 1, round(y + h) - 1
        cv2.rectangle(out, (x1, y1), (x2, y2), box_color, thickness)
        words = [str(labels[i])] if labels is not None and str(labels[i]) else []
        words += [str(ids[i])] if ids is not None else []
        if words:
            text = " ".join(words)
            (_, text_h), baseline = cv2.getTextSize(text, FONT, FONT_SCALE, 1)
            # Above the box when there is room, else below it: never over the target itself.
            text_y = y1 - thickness - baseline
            if text_y - text_h - 1 < 0:
                text_y = y2 + thickness + text_h + 1
            draw_text(out, text, (x1, text_y), box_color)
    return out


def draw_trails(
    rgb: np.ndarray,
    trails: Mapping[int, Sequence[Sequence[float]]],
    *,
    color: Color | None = None,
    thickness: int = 1,
) -> np.ndarray:
    """A copy of `rgb` with each id's trajectory drawn as a polyline through its centre points.

    `trails` maps an id to its centre points (x, y) in pixels, oldest first. Each id is drawn in
    `id_color(id)` unless a single `color` is given.
    """
    check_rgb(rgb, "frame")
    out = np.ascontiguousarray(rgb).copy()
    for track_id, points in trails.items():
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        if len(pts) == 0:
            continue
        line_color = color if color is not None else id_color(track_id)
        pixels = np.round(pts).astype(np.int32).reshape(-1, 1, 2)
        # Crisp 8-connected lines: anti-aliasing smears a 1-pixel trail into a dim band on small frames.
        cv2.polylines(out, [pixels], isClosed=False, color=line_color, thickness=thickness)
        cv2.circle(out, tuple(int(v) for v in pixels[-1, 0]), thickness + 1, line_color, cv2.FILLED)
    return out
