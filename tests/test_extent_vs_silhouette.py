"""The seen-box / whole-outline comparison takes, per target, the best IoU of any detection."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from spacetrack.config import REPO_ROOT

spec = importlib.util.spec_from_file_location(
    "extent_vs_silhouette", REPO_ROOT / "experiments/detector_cv/extent_vs_silhouette.py"
)
study = importlib.util.module_from_spec(spec)
spec.loader.exec_module(study)


def test_best_iou_per_box_over_detections():
    detections = np.array([[10, 10, 30, 20, 0.9, 0], [100, 100, 110, 110, 0.6, 2]], dtype=float)  # xyxy
    seen = np.array([[10, 10, 20, 10], [100, 100, 5, 10], [300, 300, 4, 4]], dtype=float)  # tlwh
    best = study.best_ious(detections, seen)
    assert best[0] == pytest.approx(1.0)
    assert best[1] == pytest.approx(0.5)  # half of the 10x10 detection
    assert best[2] == 0.0


def test_no_detection_or_no_box_gives_zeros():
    assert study.best_ious(np.zeros((0, 6)), np.ones((2, 4))).tolist() == [0.0, 0.0]
    assert len(study.best_ious(np.ones((1, 6)), np.zeros((0, 4)))) == 0


def test_missing_ground_truth_names_the_file(tmp_path):
    with pytest.raises(SystemExit, match="seq_x/gt/gt.txt"):
        study.gt_rows(tmp_path, "seq_x")
