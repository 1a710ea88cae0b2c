"""Pictures of a validation pass: precision-recall curves, the confusion matrix and a grid of images with
their detections."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from spacetrack.engine.metrics import CONFUSION_IOU, CONFUSION_MIN_SCORE
from spacetrack.io import atomic_path
from spacetrack.viz.draw import draw_boxes
from spacetrack.viz.sheet import contact_sheet

GT_COLOR = (0, 255, 0)
PRED_COLOR = (255, 64, 64)


def plot_pr_curves(
    curves: Mapping[int, tuple[np.ndarray, np.ndarray]], class_names: Sequence[str], path: str | Path
) -> None:
    """PNG of precision against recall at IoU 0.5, one line per class with ground truth."""
    fig = Figure(figsize=(5, 4), dpi=100)
    ax = fig.subplots()
    for cls, (recall, precision) in sorted(curves.items()):
        ax.plot(np.r_[0, recall], np.r_[1, precision], label=class_names[cls])
    ax.set(xlabel="recall", ylabel="precision", xlim=(0, 1), ylim=(0, 1.02), title="validation, IoU 0.5")
    ax.legend(loc="lower left")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")


def plot_confusion_matrix(matrix: np.ndarray, class_names: Sequence[str], path: str | Path) -> None:
    """PNG of `confusion_matrix` counts (row: true class, column: predicted class, plus `background` for
    detections of nothing and `missed` for targets found by none), each cell shaded by its share of its
    row."""
    rows = [*class_names, "background"]
    cols = [*class_names, "missed"]
    share = matrix / np.maximum(matrix.sum(axis=1, keepdims=True), 1)
    fig = Figure(figsize=(1.2 * len(cols) + 1.6, 1.0 * len(rows) + 1.2), dpi=100)
    ax = fig.subplots()
    ax.imshow(share, cmap="Blues", vmin=0, vmax=1)
    for (r, c), count in np.ndenumerate(matrix):
        ax.text(c, r, str(count), ha="center", va="center", color="white" if share[r, c] > 0.6 else "black")
    ax.set_xticks(range(len(cols)), cols, rotation=30, ha="right")
    ax.set_yticks(range(len(rows)), rows)
    title = f"validation, score >= {CONFUSION_MIN_SCORE}, IoU >= {CONFUSION_IOU}"
    ax.set(xlabel="predicted", ylabel="true", title=title)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")


def prediction_grid(
    examples: Mapping[str, object],
    class_names: Sequence[str],
    *,
    min_score: float = 0.25,
    max_images: int = 16,
) -> np.ndarray:
    """RGB sheet of validation images: ground truth in green, detections scoring >= `min_score` in red.

    `examples` is `evaluate`'s: `images` (B, 3, S, S) uint8, per image `detections` (n, 6) `xyxy,
    score, class` and `ground_truth` (m, 5) `xyxy, class`, in pixels of the letterboxed input.
    """
    tiles = []
    for image, det, gt in zip(
        examples["images"][:max_images], examples["detections"], examples["ground_truth"], strict=False
    ):
        rgb = np.ascontiguousarray(image.transpose(1, 2, 0))
        rgb = draw_boxes(rgb, xyxy_to_tlwh(gt[:, :4]), color=GT_COLOR)
        det = det[det[:, 4] >= min_score]
        labels = [f"{class_names[int(c)]} {s:.2f}" for s, c in det[:, 4:6]]
        tiles.append(draw_boxes(rgb, xyxy_to_tlwh(det[:, :4]), labels=labels, color=PRED_COLOR))
    return contact_sheet(tiles, cols=min(4, len(tiles)))


def xyxy_to_tlwh(boxes: np.ndarray) -> np.ndarray:
    """(N, 4) `x1, y1, x2, y2` -> `x, y, w, h` (top-left and size)."""
    return np.column_stack((boxes[:, :2], boxes[:, 2:4] - boxes[:, :2])).reshape(-1, 4)
