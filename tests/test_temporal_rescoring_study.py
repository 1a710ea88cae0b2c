"""experiments/detector_cv/temporal_rescoring.py: smoothing along links to the previous frame."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from spacetrack.config import REPO_ROOT

spec = importlib.util.spec_from_file_location(
    "temporal_rescoring", REPO_ROOT / "experiments/detector_cv/temporal_rescoring.py"
)
study = importlib.util.module_from_spec(spec)
spec.loader.exec_module(study)


def det(box, obj, probs):
    """A `detect_sequence` row: box, score, class, objectness, class probabilities."""
    probs = np.asarray(probs, dtype=float)
    return [*box, obj * probs.max(), float(probs.argmax()), obj, *probs]


def frames():
    first = np.array(
        [det([100, 100, 120, 120], 0.9, [0.1, 0.8, 0.1]), det([300, 300, 320, 320], 0.2, [0.5, 0.3, 0.2])]
    )
    # the target moved 2 px (IoU 0.82 with its last box) and is named debris now; a new box far away
    second = np.array(
        [det([102, 100, 122, 120], 0.5, [0.1, 0.3, 0.6]), det([500, 50, 510, 60], 0.4, [1.0, 0.0, 0.0])]
    )
    return [first, second]


def test_the_detector_alone_keeps_every_score_and_name():
    out = study.rescore(frames(), 1.0, 1.0)
    for (boxes, score, cls), det_rows in zip(out, frames(), strict=True):
        assert boxes.tolist() == det_rows[:, :4].tolist()
        assert score.tolist() == pytest.approx(det_rows[:, 4].tolist())
        assert cls.tolist() == det_rows[:, 5].tolist()


def test_a_linked_detection_carries_its_past_and_an_unlinked_one_does_not():
    (_, _, _), (_, score, cls) = study.rescore(frames(), 0.5, 0.5)
    # objectness (0.5 + 0.9) / 2 = 0.7; classes weighted 0.5 * 0.5 now against 0.5 * 0.9 before:
    # (0.25 * [0.1, 0.3, 0.6] + 0.45 * [0.1, 0.8, 0.1]) / 0.7 -> rocket body again, p = 0.6214
    assert cls[0] == 1.0
    assert score[0] == pytest.approx(0.7 * (0.25 * 0.3 + 0.45 * 0.8) / 0.7)
    assert (score[1], cls[1]) == (pytest.approx(0.4), 0.0)  # nothing before it within IoU 0.5


def test_each_predecessor_is_taken_once_by_the_best_scored_detection():
    first = np.array([det([100, 100, 120, 120], 0.9, [1.0, 0.0, 0.0])])
    second = np.array(
        [det([100, 100, 120, 120], 0.3, [0.0, 0.0, 1.0]), det([101, 100, 121, 120], 0.8, [0.0, 1.0, 0.0])]
    )
    _, (_, score, cls) = study.rescore([first, second], 0.5, 1.0)
    assert score.tolist() == pytest.approx(
        [0.3, 0.85]
    )  # the 0.8 box links (0.8 + 0.9) / 2; the 0.3 box stays
    assert cls.tolist() == [2.0, 1.0]
