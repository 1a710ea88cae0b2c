"""Scoring motion masks against ground truth: pixel precision/recall/F1 and blob-level recall/precision.

The renderer's masks cover every unoccluded pixel of a moving target, also the parts in shadow that are as
black as space and that no camera-based detector can see. The `lit_` pixel scores leave those out: truth
pixels marked `dark` count neither as found nor as missed, and a mask pixel on them is not false.

Pure functions of plain arrays (reading files is the caller's business). A moving target is found when some
blob's box overlaps its ground-truth box with IoU >= `blob_iou`; a blob is correct when it overlaps some
visible moving target that way. Static objects and stars have no ground-truth box, so a blob on them is
a false one. With a `DynamicFilter`, the identification of dynamic targets is scored too: the visible
moving targets' and static objects' true boxes stand in for detector boxes, and each should come out
dynamic and static respectively.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from spacetrack.motion.blobs import blob_boxes, find_blobs
from spacetrack.motion.dynamic import DynamicFilter
from spacetrack.tracking.iou_matching import iou_matrix


def ratio(num: float, den: float) -> float:
    """num / den, or 0 when den is 0 (nothing to find counts as nothing found, not as perfect)."""
    return float(num) / den if den > 0 else 0.0


@dataclass
class MotionScore:
    """Counts accumulated over frames; `summary()` turns them into rates.

    Attributes:
        tp, fp, fn: moving pixels found, pixels wrongly marked moving, moving pixels missed.
        lit_tp, lit_fp, lit_fn: the same without the dark truth pixels.
        targets, targets_found: visible moving targets, and those some blob matched.
        blobs, blobs_correct: blobs, and those that matched some target.
        moving_boxes, moving_dynamic: moving targets' boxes given to the dynamic filter, and those it
            marked dynamic.
        static_boxes, static_static: static objects' boxes given to it, and those it marked static.
        frames: frames scored.
    """

    tp: int = 0
    fp: int = 0
    fn: int = 0
    lit_tp: int = 0
    lit_fp: int = 0
    lit_fn: int = 0
    targets: int = 0
    targets_found: int = 0
    blobs: int = 0
    blobs_correct: int = 0
    moving_boxes: int = 0
    moving_dynamic: int = 0
    static_boxes: int = 0
    static_static: int = 0
    frames: int = 0

    def add_frame(
        self,
        mask: np.ndarray,
        truth: np.ndarray,
        target_boxes: np.ndarray,
        *,
        dark: np.ndarray | None = None,
        static_boxes: np.ndarray | None = None,
        dynamic: DynamicFilter | None = None,
        blob_iou: float = 0.3,
        min_blob_area: float = 4.0,
    ) -> None:
        """Score one frame: `mask` and `truth` (H, W) (non-zero = moving), targets as (N, 4) tlwh pixels.

        `dark` (H, W) bool marks pixels too dark to see (only its truth pixels matter); None: none are.
        With `dynamic`, the targets and the static objects' `static_boxes` (M, 4) tlwh are classified.
        Blobs enclosing less than `min_blob_area` px² are ignored (single noisy pixels are not detections).
        """
        if mask.shape != truth.shape or (dark is not None and dark.shape != truth.shape):
            raise ValueError(
                f"mask shape {mask.shape} (or dark's) differs from ground-truth shape {truth.shape}"
            )
        pred, true = mask > 0, truth > 0
        hit, false, miss = pred & true, pred & ~true, ~pred & true
        self.tp += int(np.count_nonzero(hit))
        self.fp += int(np.count_nonzero(false))
        self.fn += int(np.count_nonzero(miss))
        seen = ~dark if dark is not None else np.ones_like(true)
        self.lit_tp += int(np.count_nonzero(hit & seen))
        self.lit_fp += int(np.count_nonzero(false))
        self.lit_fn += int(np.count_nonzero(miss & seen))
        blobs = find_blobs(pred.astype(np.uint8), min_area=min_blob_area)
        match = iou_matrix(target_boxes, blob_boxes(blobs)) >= blob_iou
        self.targets += match.shape[0]
        self.targets_found += int(match.any(axis=1).sum())
        self.blobs += match.shape[1]
        self.blobs_correct += int(match.any(axis=0).sum())
        if dynamic is not None:
            static = np.zeros((0, 4)) if static_boxes is None else np.asarray(static_boxes).reshape(-1, 4)
            self.moving_boxes += len(target_boxes)
            self.moving_dynamic += int(dynamic(target_boxes, blobs).sum())
            self.static_boxes += len(static)
            self.static_static += int((~dynamic(static, blobs)).sum())
        self.frames += 1

    def merge(self, other: MotionScore) -> MotionScore:
        """A new score holding the counts of both."""
        return MotionScore(**{f.name: getattr(self, f.name) + getattr(other, f.name) for f in fields(self)})

    def summary(self) -> dict[str, float]:
        """pixel_ and lit_ precision, recall and f1, pixel_f1_ceiling (see below), blob_recall,
        blob_precision, dynamic_recall (moving targets marked dynamic), static_rejection (static objects
        marked static), all 0-1, and frames.

        The two identification rates are NaN when there was nothing to classify (no dynamic filter, or no
        static object in the frames): unlike a miss, there is no score to give.
        """
        nan = float("nan")
        return {
            "pixel_precision": ratio(self.tp, self.tp + self.fp),
            "pixel_recall": ratio(self.tp, self.tp + self.fn),
            "pixel_f1": ratio(2 * self.tp, 2 * self.tp + self.fp + self.fn),
            "lit_precision": ratio(self.lit_tp, self.lit_tp + self.lit_fp),
            "lit_recall": ratio(self.lit_tp, self.lit_tp + self.lit_fn),
            "lit_f1": ratio(2 * self.lit_tp, 2 * self.lit_tp + self.lit_fp + self.lit_fn),
            # pixel_f1 of a mask holding exactly the truth pixels that are not dark: the best score of a
            # detector that marks only what the camera shows (2 lit / (lit + all truth pixels))
            "pixel_f1_ceiling": ratio(
                2 * (self.lit_tp + self.lit_fn), self.lit_tp + self.lit_fn + self.tp + self.fn
            ),
            "blob_recall": ratio(self.targets_found, self.targets),
            "blob_precision": ratio(self.blobs_correct, self.blobs),
            "dynamic_recall": ratio(self.moving_dynamic, self.moving_boxes) if self.moving_boxes else nan,
            "static_rejection": ratio(self.static_static, self.static_boxes) if self.static_boxes else nan,
            "frames": float(self.frames),
        }
