"""experiments/detector_cv/box_extent.py: each target's group from the detections of one image."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from spacetrack.config import REPO_ROOT

spec = importlib.util.spec_from_file_location(
    "box_extent", REPO_ROOT / "experiments/detector_cv/box_extent.py"
)
study = importlib.util.module_from_spec(spec)
spec.loader.exec_module(study)

GT = np.array([[100, 100, 140, 140], [300, 300, 340, 340], [500, 100, 540, 140], [10, 400, 50, 440]], float)
CLASSES = np.array([0, 1, 2, 0])


def det(box, score, cls):
    return [*box, score, cls]


def test_each_target_gets_its_group():
    detections = np.array([
        det([101, 99, 141, 139], 0.9, 0),   # target 0, right class
        det([301, 301, 339, 341], 0.8, 2),  # target 1, wrong class
        det([510, 110, 525, 125], 0.7, 2),  # target 2: a small box inside it (IoU 0.14)
        det([10, 400, 50, 440], 0.3, 0),    # target 3: right box, but below the score threshold
        det([200, 200, 240, 240], 0.3, 0),  # on no target
    ])  # fmt: skip
    out = study.classify(detections, np.vstack([GT, [[600, 400, 640, 440]]]), np.append(CLASSES, 1))
    assert out["groups"] == ["found", "wrong_class", "partial", "low_score", "missed"]
    assert out["inside"] == [pytest.approx(1.0)]
    assert out["area_ratio"] == [pytest.approx(15 * 15 / (40 * 40))]
    # any class, one to one: targets 0 and 1 at IoU 0.5; target 2 too at 0.1
    assert out["recall_any"] == [2, 2, 3]


def test_one_detection_claims_one_target():
    # two targets side by side and one box over both (IoU 0.53 and 0.45): the first claims it, the
    # second is left with a box that overlaps it
    gt = np.array([[0, 0, 20, 20], [20, 0, 40, 20]], float)
    out = study.classify(np.array([det([0, 0, 38, 20], 0.9, 0)]), gt, np.array([0, 0]))
    assert out["groups"] == ["found", "partial"]
    assert out["area_ratio"] == [pytest.approx(38 / 20)]
    assert out["recall_any"] == [1, 1, 1]


def test_summary_pools_images():
    parts = [study.classify(np.zeros((0, 6)), GT, CLASSES),
             study.classify(np.array([det([100, 100, 140, 140], 0.9, 0)]), GT[:1], CLASSES[:1])]  # fmt: skip
    s = study.summarise(parts)
    assert (s["targets"], s["found"], s["missed"], s["partial"], s["low_score"]) == (5, 1, 4, 0, 0)
    assert s["recall_any_0.5"] == pytest.approx(0.2)
    assert s["partial_inside_median"] is None
