import numpy as np
import pytest
import torch

from spacetrack.engine.metrics import (
    box_iou,
    confusion_matrix,
    detection_metrics,
    interpolated_ap,
    match_detections,
)
from spacetrack.engine.nms import non_max_suppression

GT = np.array([[0, 0, 10, 10], [50, 50, 60, 60]], dtype=float)


def test_hand_built_image_has_known_map():
    # A: exact hit on box 0 (score .9); B: on nothing (.8); C: IoU 0.62 with box 1 (.7).
    preds = np.array([[0, 0, 10, 10], [100, 100, 110, 110], [50, 50, 60, 56.2]], dtype=float)
    scores = np.array([0.9, 0.8, 0.7])
    classes = np.zeros(3)
    tp = match_detections(preds, scores, classes, GT, np.zeros(2))
    assert tp[0].all() and not tp[1].any()
    assert tp[2].tolist() == [True] * 3 + [False] * 7  # thresholds 0.50, 0.55, 0.60 <= 0.62
    out = detection_metrics(tp, scores, classes, np.zeros(2))
    # IoU 0.5: recall .5,.5,1 with precision 1,.5,2/3 -> 51 points at 1 and 50 at 2/3 of 101.
    ap_hit = (51 + 50 * 2 / 3) / 101
    ap_miss = 51 / 101
    assert out["map50"] == pytest.approx(ap_hit)
    assert out["map50_95"] == pytest.approx((3 * ap_hit + 7 * ap_miss) / 10)
    # Best F1 keeps all three detections: precision 2/3, recall 1.
    assert out["precision"] == pytest.approx(2 / 3, abs=1e-3)
    assert out["recall"] == pytest.approx(1.0)


def test_greedy_matching_by_score_and_class():
    preds = np.array([[0, 0, 10, 10], [0, 0, 10, 9], [50, 50, 60, 60]], dtype=float)
    tp = match_detections(preds, np.array([0.5, 0.9, 0.8]), np.array([0, 0, 1]), GT, np.array([0, 0]))
    # The higher-scored near-duplicate claims box 0 first; the third has the wrong class.
    assert tp[:, 0].tolist() == [False, True, False]


def test_perfect_detector_and_a_class_without_predictions():
    tp = match_detections(GT, np.array([0.9, 0.8]), np.zeros(2), GT, np.zeros(2))
    assert detection_metrics(tp, np.array([0.9, 0.8]), np.zeros(2), np.zeros(2))["map50_95"] == pytest.approx(
        1.0
    )
    # A second class with ground truth but no detection halves the mean.
    out = detection_metrics(tp, np.array([0.9, 0.8]), np.zeros(2), np.array([0, 0, 1]))
    assert out["map50"] == pytest.approx(0.5)


def test_interpolated_ap_uses_the_precision_envelope():
    assert interpolated_ap(np.array([0.5, 1.0]), np.array([0.5, 1.0])) == pytest.approx(1.0)
    assert interpolated_ap(np.array([]), np.array([])) == 0.0


def test_box_iou():
    assert box_iou(GT, GT).round(6).tolist() == [[1.0, 0.0], [0.0, 1.0]]


def test_nms_keeps_the_best_of_overlapping_boxes_per_class():
    # Rows cx, cy, w, h, objectness, class scores (2 classes).
    pred = torch.tensor(
        [
            [
                [20, 20, 10, 10, 0.9, 0.9, 0.1],
                [21, 20, 10, 10, 0.8, 0.9, 0.1],
                [21, 20, 10, 10, 0.8, 0.1, 0.9],
                [80, 80, 10, 10, 0.0001, 0.9, 0.1],
            ]
        ]
    )
    (out,) = non_max_suppression(pred, conf_threshold=0.01, iou_threshold=0.5)
    assert out[:, 5].tolist() == [0.0, 1.0]
    assert out[0, :4].tolist() == [15.0, 15.0, 25.0, 25.0]
    assert out[0, 4].item() == pytest.approx(0.81)


def test_multi_label_nms_keeps_every_class_an_anchor_scores_above_the_threshold():
    # One anchor, objectness 0.9, classes 0.1 / 0.8 / 0.6: scores 0.09, 0.72, 0.54
    pred = torch.tensor([[[40, 40, 20, 10, 0.9, 0.1, 0.8, 0.6], [90, 90, 8, 8, 0.9, 0.3, 0.2, 0.1]]])
    (best,) = non_max_suppression(pred, conf_threshold=0.3, iou_threshold=0.5)
    assert best[:, 5].tolist() == [1.0]  # one class per anchor; the second anchor's best 0.27 is under 0.3
    assert best[0, 4].item() == pytest.approx(0.72)
    (every,) = non_max_suppression(pred, conf_threshold=0.3, iou_threshold=0.5, multi_label=True)
    assert every[:, 5].tolist() == [1.0, 2.0]  # best score first; the same box under both names
    assert every[:, 4].tolist() == pytest.approx([0.72, 0.54])
    assert every[0, :4].tolist() == every[1, :4].tolist() == [30.0, 35.0, 50.0, 45.0]


def test_nms_with_probabilities_carries_the_kept_anchors_objectness_and_class_probabilities():
    pred = torch.tensor([[[40, 40, 20, 10, 0.9, 0.1, 0.8, 0.6], [41, 40, 20, 10, 0.5, 0.1, 0.9, 0.2]]])
    (plain,) = non_max_suppression(pred, conf_threshold=0.3, iou_threshold=0.5)
    (out,) = non_max_suppression(pred, conf_threshold=0.3, iou_threshold=0.5, probabilities=True)
    assert out.shape == (1, 10)  # x1, y1, x2, y2, score, class, objectness, three class probabilities
    assert out[:, :6].tolist() == plain.tolist()  # the first anchor (0.72) suppresses the second (0.45)
    assert out[0, 6:].tolist() == pytest.approx([0.9, 0.1, 0.8, 0.6])
    with pytest.raises(ValueError, match="multi_label detections do not carry"):
        non_max_suppression(pred, multi_label=True, probabilities=True)


def test_objectness_score_keeps_a_box_the_model_cannot_name_and_still_names_it_by_its_best_class():
    # Objectness 0.9, classes 0.45 / 0.40 / 0.1: a target the model splits between two names.
    pred = torch.tensor([[[40, 40, 20, 10, 0.9, 0.45, 0.40, 0.1], [90, 90, 8, 8, 0.2, 0.9, 0.1, 0.1]]])
    (by_class,) = non_max_suppression(pred, conf_threshold=0.5, iou_threshold=0.5)
    assert len(by_class) == 0  # 0.9 x 0.45 = 0.405 and 0.18: nothing reaches 0.5
    (by_object,) = non_max_suppression(pred, conf_threshold=0.5, iou_threshold=0.5, score="objectness")
    assert by_object[:, 4].tolist() == pytest.approx([0.9])
    assert by_object[:, 5].tolist() == [0.0]
    assert by_object[0, :4].tolist() == [30.0, 35.0, 50.0, 45.0]
    with pytest.raises(ValueError, match="score must be one of class, objectness, got 'max'"):
        non_max_suppression(pred, score="max")
    with pytest.raises(ValueError, match="multi_label"):
        non_max_suppression(pred, multi_label=True, score="objectness")


def test_confusion_matrix_pairs_boxes_whatever_their_class():
    gt = np.array([[0, 0, 10, 10], [20, 20, 30, 30], [50, 50, 60, 60]], dtype=float)
    gt_cls = np.array([0, 1, 2])
    pred = np.array([[0, 0, 10, 10], [21, 20, 31, 30], [80, 80, 90, 90], [50, 50, 60, 60]], dtype=float)
    scores = np.array([0.9, 0.8, 0.7, 0.1])  # the last one finds target 3 but under min_score
    pred_cls = np.array([0, 2, 1, 2])  # right, wrong name (1 called 2), nothing there
    matrix = confusion_matrix(pred, scores, pred_cls, gt, gt_cls, 3)
    expected = np.zeros((4, 4), dtype=int)
    expected[0, 0] = 1  # found and named right
    expected[1, 2] = 1  # a rocket body called debris: off the diagonal, not a miss and a false positive
    expected[2, 3] = 1  # missed
    expected[3, 1] = 1  # a detection of nothing
    np.testing.assert_array_equal(matrix, expected)
    # one detection pairs with one target: the second box on the same target is a false positive
    twice = confusion_matrix(pred[[0, 0]], np.array([0.9, 0.8]), np.array([0, 1]), gt[:1], gt_cls[:1], 3)
    assert twice[0, 0] == 1 and twice[3, 1] == 1 and twice.sum() == 2
    assert confusion_matrix(pred[:0], scores[:0], pred_cls[:0], gt, gt_cls, 3)[:3, 3].tolist() == [1, 1, 1]
