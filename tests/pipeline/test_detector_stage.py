"""The detector stage on a random-init checkpoint: boxes come back in the frame's own pixels."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from spacetrack.engine.checkpoint import save_checkpoint
from spacetrack.models.yolo import YOLOv5
from spacetrack.pipeline import YoloDetector


def random_checkpoint(tmp_path):
    """A random-init three-class YOLOv5 (narrow) saved as a `best.pt`."""
    torch.manual_seed(0)
    model = YOLOv5(num_classes=3, depth_multiple=0.33, width_multiple=0.125)
    weights = tmp_path / "best.pt"
    save_checkpoint(weights, {"arch": model.arch, "ema": model.state_dict()})
    return weights


def test_boxes_are_tlwh_inside_the_frame(tmp_path):
    weights = random_checkpoint(tmp_path)
    detector = YoloDetector(weights=weights, image_size=128, conf_threshold=0.0, max_det=50, device="cpu")
    rgb = np.random.default_rng(0).integers(0, 255, (90, 200, 3), dtype=np.uint8)
    boxes = detector(rgb, 1)
    assert boxes.shape[1] == 6 and 0 < len(boxes) <= 50
    x, y, w, h = boxes[:, :4].T
    assert (x >= 0).all() and (y >= 0).all() and (w > 0).all() and (h > 0).all()
    assert (x + w <= 200 + 1e-6).all() and (y + h <= 90 + 1e-6).all()
    assert set(np.unique(boxes[:, 5])) <= {0, 1, 2}
    with pytest.raises(ValueError, match="multiple of 32"):
        YoloDetector(weights=weights, image_size=100)


def detector_pair(tmp_path, seed: int, iou_threshold: float, **changed):
    """A random 64x96 frame, and a random checkpoint as two detectors keeping every box NMS leaves: with
    the defaults, and with `changed`."""
    rgb = np.random.default_rng(seed).integers(0, 255, (64, 96, 3), dtype=np.uint8)
    kwargs = {
        "weights": random_checkpoint(tmp_path),
        "conf_threshold": 0.0,
        "iou_threshold": iou_threshold,
        "max_det": 10_000,
        "device": "cpu",
    }
    return rgb, YoloDetector(**kwargs), YoloDetector(**kwargs, **changed)


def test_objectness_scores_are_never_below_class_scores_and_name_the_score_in_the_identity(tmp_path):
    rgb, by_class, by_object = detector_pair(tmp_path, 1, iou_threshold=1.0, score="objectness")
    class_boxes, object_boxes = by_class(rgb, 1), by_object(rgb, 1)
    assert len(class_boxes) == len(object_boxes) > 0  # NMS off: one box per anchor either way
    assert object_boxes[:, 4].max() > class_boxes[:, 4].max()  # a class probability is under 1
    assert "score=" not in by_class.identity and "score=objectness" in by_object.identity
    with pytest.raises(ValueError, match="detector.score must be one of class, objectness, got 'best'"):
        YoloDetector(weights=by_class.weights, score="best")


def test_agnostic_nms_reaches_the_detector_and_names_itself(tmp_path):
    rgb, per_class, agnostic = detector_pair(tmp_path, 2, iou_threshold=0.3, agnostic_nms=True)
    kept_per_class, kept_agnostic = per_class(rgb, 1), agnostic(rgb, 1)
    assert 0 < len(kept_agnostic) < len(kept_per_class)  # boxes of other classes now suppress each other
    assert len(np.unique(kept_agnostic[:, 5])) > 1  # each box keeps its own name
    assert "nms=" not in per_class.identity and "nms=agnostic" in agnostic.identity


def test_part_overlap_drops_every_box_mostly_inside_a_higher_scored_one(tmp_path):
    rgb, whole, parted = detector_pair(tmp_path, 3, iou_threshold=0.45, part_overlap=0.8)
    kept, before = parted(rgb, 1), whole(rgb, 1)
    assert 0 < len(kept) < len(before)
    assert (np.diff(kept[:, 4]) <= 0).all()  # still best score first
    x1, y1, w, h = kept[:, :4].T
    iw = np.minimum(x1[:, None] + w[:, None], (x1 + w)[None]) - np.maximum(x1[:, None], x1[None]) + 1
    ih = np.minimum(y1[:, None] + h[:, None], (y1 + h)[None]) - np.maximum(y1[:, None], y1[None]) + 1
    inside = np.clip(iw, 0, None) * np.clip(ih, 0, None) / ((w + 1) * (h + 1))[None, :]
    assert not np.triu(inside > 0.8, k=1).any()  # no box lies 80 % inside one scored above it
    assert "part_overlap=0.8" in parted.identity and "part_overlap" not in whole.identity
    with pytest.raises(ValueError, match="detector.part_overlap must lie in \\(0, 1\\] or be null, got 1.5"):
        YoloDetector(weights=whole.weights, part_overlap=1.5)
