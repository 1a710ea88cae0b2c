"""Validation metrics of several loaders pool into the metrics of one loader over them all."""

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from detector_helpers import tiny_model
from spacetrack.data.yolo_dataset import YoloDataset, collate
from spacetrack.engine.metrics import detection_metrics
from spacetrack.engine.validate import evaluate

KEYS = ("map50", "map50_95", "precision", "recall", "recall_at_score")


def run(model, root, names):
    data = YoloDataset(root=root, sequences=names, num_classes=3)
    loader = DataLoader(data, batch_size=2, collate_fn=collate)
    return evaluate(model, loader, device=torch.device("cpu"), conf_threshold=0.001, iou_threshold=0.6,
                    max_det=300)  # fmt: skip


def test_pooled_matches_give_the_metrics_of_all_frames_at_once(tiny_dataset):
    torch.manual_seed(0)
    model = tiny_model().eval()
    names = ["seq_000_nominal", "seq_001_nominal", "seq_002_nominal"]
    whole, details = run(model, tiny_dataset, names)
    parts = [run(model, tiny_dataset, [n])[1]["matches"] for n in names]
    pooled = [np.concatenate(a) for a in zip(*parts, strict=True)]
    tps, scores, _, gt_classes = details["matches"]
    assert len(gt_classes) == 12 and len(scores) > 0  # 3 sequences x 4 frames x 1 box; detections made
    for mine, theirs in zip(pooled, details["matches"], strict=True):
        np.testing.assert_array_equal(mine, theirs)
    result = detection_metrics(*pooled)
    for key in KEYS:
        assert float(result[key]) == pytest.approx(whole[key], abs=1e-12), key
