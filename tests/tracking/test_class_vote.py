"""Each track's class, voted over its matched detections."""

import numpy as np
import pytest

from spacetrack.tracking import DeepSort
from spacetrack.tracking.class_vote import UNKNOWN, ClassVotes

SETTINGS = dict(
    max_cosine_distance=None, nn_budget=None, max_iou_distance=0.7, max_age=30, n_init=2,
    min_confidence=0.3, nms_max_overlap=1.0, reacquire_gate=13.8155,
)  # fmt: skip


def test_the_vote_is_weighted_by_score_and_ties_go_to_the_lower_index():
    votes = ClassVotes()
    for k, score in [(2, 0.9), (1, 0.5), (1, 0.5), (UNKNOWN, 0.9)]:
        votes.add(7, k, score)
    assert votes.winner(7) == (1, pytest.approx(1.0 / 1.9))  # 1.0 against 0.9; the unknown box adds nothing
    votes.add(8, 2, 0.4)
    votes.add(8, 0, 0.4)
    assert votes.winner(8)[0] == 0
    assert votes.winner(9) == (UNKNOWN, 0.0)
    assert set(votes.table()) == {7, 8}


def test_a_target_named_two_ways_gets_the_name_most_of_its_boxes_carry():
    # one target moving right, named rocket body (1) on 7 of 10 frames and debris (2) on the others;
    # frame 6 has no detection (the track coasts)
    named = [1, 2, 1, 1, 2, 1, 1, 2, 1, 1]
    tracker = DeepSort(**SETTINGS)
    outputs = []
    for f, k in enumerate(named):
        seen = f != 6
        tlwh = np.array([[100 + 3 * f, 100, 20, 30]])[: int(seen)]
        tracker.step(tlwh, np.full(len(tlwh), 0.8), classes=np.array([k])[: int(seen)])
        outputs.append(tracker.output_classes())
    assert tracker.class_votes.table() == {1: (1, pytest.approx(6 / 9))}  # 6 rocket-body boxes of 9
    assert outputs[0].shape == (0, 2)  # not confirmed yet: nothing output
    assert outputs[1].tolist() == [[2, 1]]  # the frame's own name; the vote so far (0.8 each: a tie)
    assert outputs[6].tolist() == [[UNKNOWN, 1]]  # coasting: no detection of its own this frame
    assert outputs[9].tolist() == [[1, 1]]


def test_boxes_without_classes_leave_every_track_unnamed():
    tracker = DeepSort(**SETTINGS)
    for f in range(4):
        tracker.step(np.array([[100 + 3 * f, 100, 20, 30]]), np.array([0.8]))
    assert tracker.output_classes().tolist() == [[UNKNOWN, UNKNOWN]]
    assert tracker.class_votes.table() == {}
