"""Moving blobs: the outer outlines of a motion mask's regions, with centroid, box and area."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class Blob:
    """One region of a motion mask (its outer outline; holes belong to it).

    Attributes:
        centroid: (x, y) pixels, the centre of mass of the area inside the outline.
        tlwh: bounding box (top-left x, top-left y, width, height) in pixels.
        area: area inside the outline in square pixels (through pixel centres: a 3x3 square has 4).
    """

    centroid: tuple[float, float]
    tlwh: tuple[int, int, int, int]
    area: float


def outlines(mask: np.ndarray, *, min_area: float = 0.0) -> list[np.ndarray]:
    """Outer outlines (OpenCV contours) of the regions of a (H, W) uint8 mask with area >= `min_area`.

    Outlines instead of a connected-component labelling: a motion mask is mostly empty, and tracing the
    few outlines costs a fraction of labelling every pixel.
    """
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    return [c for c in contours if cv2.contourArea(c) >= min_area]


def find_blobs(mask: np.ndarray, *, min_area: float = 0.0) -> list[Blob]:
    """The regions of a (H, W) uint8 mask (non-zero = moving) whose outline encloses >= `min_area` px²."""
    blobs = []
    for contour in outlines(mask, min_area=min_area):
        x, y, w, h = (int(v) for v in cv2.boundingRect(contour))
        m = cv2.moments(contour)
        # Lines and single pixels enclose no area; their box centre stands in for the centroid.
        centroid = (m["m10"] / m["m00"], m["m01"] / m["m00"]) if m["m00"] > 0 else (x + w / 2, y + h / 2)
        blobs.append(Blob((float(centroid[0]), float(centroid[1])), (x, y, w, h), float(m["m00"])))
    return blobs


def blob_boxes(blobs: list[Blob]) -> np.ndarray:
    """(N, 4) float64 array of the blobs' boxes in tlwh pixels."""
    return np.array([b.tlwh for b in blobs], dtype=np.float64).reshape(-1, 4)
