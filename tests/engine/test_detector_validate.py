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
    assert "matches_any" not in details  # only asked for
    parts = [run(model, tiny_dataset, [n])[1]["matches"] for n in names]
    pooled = [np.concatenate(a) for a in zip(*parts, strict=True)]
    tps, scores, _, gt_classes = details["matches"]
    assert len(gt_classes) == 12 and len(scores) > 0  # 3 sequences x 4 frames x 1 box; detections made
    for mine, theirs in zip(pooled, details["matches"], strict=True):
        np.testing.assert_array_equal(mine, theirs)
    result = detection_metrics(*pooled)
    for key in KEYS:
        assert float(result[key]) == pytest.approx(whole[key], abs=1e-12), key


def test_a_box_found_with_the_wrong_class_counts_only_in_the_class_agnostic_matches(monkeypatch):
    """One target of class 1 at (16, 16)-(48, 40) of a 64x64 image; the only detection is that very box,
    called class 2: a miss for the mAP, a find for `matches_any` (what the tracker follows)."""
    import spacetrack.engine.validate as validate

    found = torch.tensor([[16.0, 16.0, 48.0, 40.0, 0.9, 2.0]])
    monkeypatch.setattr(validate, "non_max_suppression", lambda *a, **k: [found.clone()])
    images = torch.zeros(1, 3, 64, 64, dtype=torch.uint8)
    targets = torch.tensor([[0.0, 1.0, 0.5, 28 / 64, 0.5, 24 / 64]])  # image, class, cx, cy, w, h
    metrics, details = evaluate(tiny_model().eval(), [(images, targets)], device=torch.device("cpu"),
                                conf_threshold=0.001, iou_threshold=0.6, max_det=300,
                                class_agnostic=True)  # fmt: skip
    assert not details["matches"][0].any() and metrics["map50"] == 0.0
    assert details["confusion"][1, 2] == 1 and details["confusion"].sum() == 1  # true 1, called 2
    tp_any, scores, pred_any, gt_any = details["matches_any"]
    assert tp_any.all()  # every IoU threshold: the boxes are the same
    any_class = detection_metrics(*details["matches_any"])
    assert any_class["map50"] == pytest.approx(1.0) and any_class["recall_at_score"] == 1.0


def test_a_box_whose_second_class_is_right_counts_only_in_the_multi_label_matches():
    """One target of class 2 at (16, 16)-(48, 40) of a 64x64 image; the model finds that very box with
    objectness 0.9 and class scores 0.1 / 0.8 / 0.6: its best class (1) is wrong, its second (2) right."""
    model = tiny_model().eval()
    pred = torch.tensor([[[32.0, 28.0, 32.0, 24.0, 0.9, 0.1, 0.8, 0.6]]])
    model.detect.decode = lambda raw: pred
    images = torch.zeros(1, 3, 64, 64, dtype=torch.uint8)
    targets = torch.tensor([[0.0, 2.0, 0.5, 28 / 64, 0.5, 24 / 64]])  # image, class, cx, cy, w, h
    metrics, details = evaluate(model, [(images, targets)], device=torch.device("cpu"), conf_threshold=0.001,
                                iou_threshold=0.6, max_det=300, multi_label=True)  # fmt: skip
    assert metrics["map50"] == 0.0 and not details["matches"][0].any()  # one name per box: the wrong one
    tp, scores, classes, truth = details["matches_multi"]
    assert classes.tolist() == [1.0, 2.0, 0.0] and truth.tolist() == [2.0]  # 0.72, 0.54, 0.09: all > 0.001
    assert tp[:, 0].tolist() == [False, True, False] and scores[1] == pytest.approx(0.54)
    assert detection_metrics(*details["matches_multi"])["map50"] == pytest.approx(1.0)


def test_a_second_stage_renames_each_detection_from_the_image_before_matching():
    """The detector finds the class-2 target at (16, 16)-(48, 40) but calls it class 1; a second stage
    that reads the image and the detections names it 2, so the mAP and the confusion count it found."""
    model = tiny_model().eval()
    model.detect.decode = lambda raw: torch.tensor([[[32.0, 28.0, 32.0, 24.0, 0.9, 0.1, 0.8, 0.6]]])
    images = torch.zeros(1, 3, 64, 64, dtype=torch.uint8)
    images[0, :, 16:40, 16:48] = 200  # the target's pixels, what the second stage looks at
    targets = torch.tensor([[0.0, 2.0, 0.5, 28 / 64, 0.5, 24 / 64]])  # image, class, cx, cy, w, h
    seen = []

    def rename(image, detections):
        seen.append((image.shape, float(image[0, 20, 20]), float(image[0, 5, 5]), detections.copy()))
        x1, y1, x2, y2 = detections[0, :4].round().astype(int)
        return np.where(image[0, y1:y2, x1:x2].mean().item() > 0.5, 2.0, 0.0) * np.ones(len(detections))

    kwargs = {"device": torch.device("cpu"), "conf_threshold": 0.001, "iou_threshold": 0.6, "max_det": 300}
    plain, plain_details = evaluate(model, [(images, targets)], **kwargs)
    renamed, details = evaluate(model, [(images, targets)], **kwargs, rename=rename)
    assert plain["map50"] == 0.0 and plain_details["confusion"][2, 1] == 1  # true 2, called 1
    assert renamed["map50"] == pytest.approx(1.0) and details["confusion"][2, 2] == 1
    shape, inside, outside, detections = seen[0]
    assert shape == (3, 64, 64) and inside == pytest.approx(200 / 255) and outside == 0.0  # in [0, 1]
    np.testing.assert_allclose(detections[0, :5], [16, 16, 48, 40, 0.72], rtol=1e-6)
    assert detections[0, 5] == 1.0  # handed the detector's own class


def test_augmented_validation_adds_the_other_views_to_the_plain_one(tiny_dataset, monkeypatch):
    import spacetrack.engine.validate as validate

    calls = []
    real = validate.augmented_predictions

    def spy(predict, x, views):
        calls.append(list(views))
        return real(predict, x, views)

    monkeypatch.setattr(validate, "augmented_predictions", spy)
    torch.manual_seed(0)
    model = tiny_model().eval()
    data = YoloDataset(root=tiny_dataset, sequences=["seq_000_nominal"], num_classes=3)
    loader = DataLoader(data, batch_size=2, collate_fn=collate)
    kwargs = {"device": torch.device("cpu"), "conf_threshold": 0.001, "iou_threshold": 0.6, "max_det": 300}
    plain = evaluate(model, loader, **kwargs)[1]["matches"]
    assert calls == []
    augmented = evaluate(model, loader, **kwargs, augment=True)[1]["matches"]
    assert calls == [[(0.83, True), (0.67, False)]] * 2  # one call a batch; the plain view is not run twice
    assert len(augmented[3]) == len(plain[3])  # the same targets
    assert not np.array_equal(augmented[1], plain[1])  # scored on more boxes than the plain view's
