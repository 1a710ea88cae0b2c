import numpy as np
import pytest

from spacetrack.motion.dynamic import DynamicFilter
from spacetrack.motion.evaluation import MotionScore


def test_frame_scores_worked_out_by_hand():
    truth = np.zeros((20, 30), np.uint8)
    truth[2:6, 2:6] = 255  # target A, 16 px
    truth[10:14, 20:24] = 255  # target B, 16 px: missed
    mask = np.zeros_like(truth)
    mask[2:6, 3:7] = 255  # 12 px on A, 4 px beside it
    mask[15:19, 0:4] = 255  # a false blob (a star, say)
    mask[0, 29] = 255  # one noisy pixel: no blob, but a false pixel
    score = MotionScore()
    score.add_frame(mask, truth, np.array([[2, 2, 4, 4], [20, 10, 4, 4]]), blob_iou=0.3, min_blob_area=4)
    s = score.summary()
    assert (score.tp, score.fp, score.fn) == (12, 4 + 16 + 1, 20)
    assert s["pixel_precision"] == pytest.approx(12 / 33)
    assert s["pixel_recall"] == pytest.approx(12 / 32)
    assert s["pixel_f1"] == pytest.approx(24 / (24 + 21 + 20))
    # blob boxes: A's is 4x4 at x=3 (IoU 12/20 with A), the star's matches nothing
    assert (score.targets, score.targets_found, score.blobs, score.blobs_correct) == (2, 1, 2, 1)
    assert s["blob_recall"] == 0.5 and s["blob_precision"] == 0.5
    assert (score.lit_tp, score.lit_fp, score.lit_fn) == (score.tp, score.fp, score.fn)


def test_dark_truth_pixels_are_left_out_of_the_lit_scores():
    truth = np.zeros((10, 10), np.uint8)
    truth[0:4, 0:4] = 255
    dark = np.zeros((10, 10), bool)
    dark[0:4, 2:4] = True  # the shadowed half of the target
    mask = np.zeros_like(truth)
    mask[0:4, 0:3] = 255  # the lit half plus one dark column
    mask[9, 9] = 255
    score = MotionScore()
    score.add_frame(mask, truth, np.zeros((0, 4)), dark=dark)
    assert (score.tp, score.fp, score.fn) == (12, 1, 4)
    assert (score.lit_tp, score.lit_fp, score.lit_fn) == (8, 1, 0)
    assert score.summary()["lit_f1"] == pytest.approx(16 / 17)
    # 8 lit of 16 truth pixels: no mask of visible pixels scores a pixel F1 above 2*8 / (8 + 16)
    assert score.summary()["pixel_f1_ceiling"] == pytest.approx(16 / 24)
    exact = MotionScore()
    exact.add_frame(np.where(dark, 0, truth).astype(np.uint8), truth, np.zeros((0, 4)), dark=dark)
    assert exact.summary()["pixel_f1"] == pytest.approx(exact.summary()["pixel_f1_ceiling"])


def test_empty_scores_are_zero_and_merge_adds():
    empty = MotionScore().summary()
    assert empty["pixel_f1"] == 0.0 and empty["blob_recall"] == 0.0
    assert np.isnan(empty["dynamic_recall"]) and np.isnan(empty["static_rejection"])
    a = MotionScore(tp=1, fp=2, fn=3, frames=1)
    assert a.merge(a) == MotionScore(tp=2, fp=4, fn=6, frames=2)
    with pytest.raises(ValueError, match="shape"):
        a.add_frame(np.zeros((2, 2)), np.zeros((3, 2)), np.zeros((0, 4)))


def test_dynamic_identification_is_scored_on_true_moving_and_static_boxes():
    truth = np.zeros((40, 40), np.uint8)
    truth[5:12, 5:12] = 255
    mask = truth.copy()
    mask[30:36, 30:36] = 255  # motion on the static object too: it will be called dynamic
    static = np.array([[30, 30, 6, 6], [20, 2, 5, 5]])
    score = MotionScore()
    score.add_frame(mask, truth, np.array([[5, 5, 7, 7]]), static_boxes=static, dynamic=DynamicFilter())
    assert (score.moving_boxes, score.moving_dynamic, score.static_boxes, score.static_static) == (1, 1, 2, 1)
    s = score.summary()
    assert s["dynamic_recall"] == 1.0 and s["static_rejection"] == 0.5
