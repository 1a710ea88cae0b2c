"""Hand-built sequences whose correct tracks are known, run through the full DeepSORT step."""

import numpy as np
import pytest

from spacetrack.tracking import DeepSort

ORIGINAL = dict(
    max_cosine_distance=0.2,
    nn_budget=100,
    max_iou_distance=0.7,
    max_age=70,
    n_init=3,
    min_confidence=0.3,
    nms_max_overlap=0.5,
)
FEATURES = np.eye(4)  # one orthogonal appearance per target: cosine distance 0 to itself, 1 to others


def run(frames, **overrides):
    """frames: list of per-frame lists of (x, y, w, h, feature index). Returns [{id: tlwh}] per frame."""
    tracker = DeepSort(**{**ORIGINAL, **overrides})
    outputs = []
    for dets in frames:
        tlwh = np.array([d[:4] for d in dets], dtype=float).reshape(-1, 4)
        feature = np.array([FEATURES[d[4]] for d in dets]).reshape(-1, 4)
        rows = tracker.step(tlwh, np.full(len(dets), 0.9), feature)
        outputs.append({int(r[0]): r[1:] for r in rows})
    return outputs


def ids_near(output, x, tol=5.0):
    return [k for k, box in output.items() if abs(box[0] - x) < tol]


def test_a_track_is_output_from_its_n_init_th_hit_with_the_filtered_box():
    frames = [[(100 + 2 * f + (0.7 if f % 2 else -0.7), 100, 20, 40, 0)] for f in range(6)]
    out = run(frames)
    assert [len(o) for o in out] == [0, 0, 1, 1, 1, 1]
    assert set(out[2]) == {1}
    # the Kalman state, not the detection, is written: they differ on noisy input
    assert not np.isclose(out[5][1][0], frames[5][0][0])
    assert abs(out[5][1][0] - frames[5][0][0]) < 2


def test_crossing_targets_keep_their_identities():
    # two targets swap places horizontally over 30 frames and overlap heavily in the middle
    frames = [[(100 + 5 * f, 100, 20, 40, 0), (245 - 5 * f, 104, 20, 40, 1)] for f in range(30)]
    out = run(frames)
    first, last = out[3], out[-1]
    left_id = ids_near(first, 115)[0]
    right_id = ids_near(first, 230)[0]
    assert ids_near(last, 100 + 5 * 29) == [left_id]
    assert ids_near(last, 245 - 5 * 29) == [right_id]
    assert set().union(*out) == {left_id, right_id}  # no identity was ever created anew


def test_missed_detections_are_bridged_by_the_cascade():
    # a confirmed target is missed for 5 frames and comes back where its motion predicts
    frames = [[(100 + 4 * f, 100, 20, 40, 0)] if not 10 <= f < 15 else [] for f in range(25)]
    out = run(frames)
    assert out[9].keys() == {1}
    assert out[10].keys() == {1}  # first missed frame: still written (predicted box)
    assert all(not out[f] for f in range(11, 15))  # later missed frames: not written
    assert out[15].keys() == {1}  # the same identity resumes
    assert abs(out[15][1][0] - (100 + 4 * 15)) < 2


def test_a_tentative_track_dies_on_its_first_miss():
    frames = [[(100, 100, 20, 40, 0)], [(100, 100, 20, 40, 0)], [], *[[(100, 100, 20, 40, 0)]] * 4]
    out = run(frames)
    assert all(not o for o in out[:5])  # the first track (id 1) never reached n_init = 3 hits
    assert out[5].keys() == {2} and out[6].keys() == {2}  # the target came back as a new track


@pytest.mark.parametrize(("gap", "same_id"), [(2, True), (3, False)])
def test_a_confirmed_track_is_deleted_after_max_age_misses(gap, same_id):
    # On its return the track has gone gap + 1 frames without an update; the cascade reaches back
    # max_age frames, so a gap of max_age frames can no longer be bridged (as in the reference).
    still = (100, 100, 20, 40, 0)
    frames = [[still]] * 5 + [[]] * gap + [[still]] * 4
    out = run(frames, max_age=3)
    assert out[4].keys() == {1}
    assert out[-1].keys() == ({1} if same_id else {2})


def test_lambda_weights_motion_against_appearance_eq_15():
    # Two parallel targets 6 px apart with similar appearances (cosine distance 0.05); in frame 12
    # their features are exchanged. Appearance alone (lambda 0) follows the features and swaps the
    # identities; with lambda 0.9 the motion term dominates and keeps them.
    a = np.array([1.0, 0.0, 0.0, 0.0])
    b = np.array([0.95, np.sqrt(1 - 0.95**2), 0.0, 0.0])
    global FEATURES
    saved, FEATURES = FEATURES, np.stack([a, b, a, b])
    try:
        frames = [
            [(100 + 3 * f, 100, 20, 40, 0 if f != 12 else 1), (100 + 3 * f, 106, 20, 40, 1 if f != 12 else 0)]
            for f in range(16)
        ]
        for lambda_, swapped in [(0.0, True), (0.9, False)]:
            out = run(frames, lambda_=lambda_, nms_max_overlap=1.0)
            top_before = [k for k, box in out[11].items() if box[1] < 103]
            top_after = [k for k, box in out[12].items() if box[1] < 103]
            assert (top_before != top_after) == swapped, lambda_
    finally:
        FEATURES = saved


def test_sort_preset_tracks_by_iou_alone():
    frames = [[(100 + 2 * f, 100, 20, 40, f % 4)] for f in range(8)]  # appearance changes every frame
    out = run(frames, max_cosine_distance=None, nn_budget=None, max_age=1)
    assert all(o.keys() == {1} for o in out[2:])


def _occluded_target(other_target_at=None):
    """A target moving 3 px/frame right, hidden for frames 20-39, back from frame 40 with another
    appearance (feature 1, as a partly visible re-ID crop looks); optionally a second target (feature 2)
    that appears at x = `other_target_at` while the first is hidden."""
    frames = []
    for f in range(60):
        dets = [] if 20 <= f < 40 else [(100 + 3 * f, 100, 20, 40, 0 if f < 20 else 1)]
        if other_target_at is not None and f >= 30:
            dets.append((other_target_at, 300, 20, 40, 2))
        frames.append(dets)
    return frames


def test_a_target_back_from_an_occlusion_keeps_its_identity_with_reacquire_gate():
    reference = run(_occluded_target())
    assert set(reference[10]) != set(reference[50])  # the reference's appearance gate turns it away
    out = run(_occluded_target(), reacquire_gate=13.8155)
    assert set(out[10]) == set(out[50]) == {1}
    assert abs(out[50][1][0] - (100 + 3 * 50)) < 2


def test_reacquire_gate_leaves_a_new_target_far_from_the_prediction_its_own_track():
    out = run(_occluded_target(other_target_at=400), reacquire_gate=13.8155)
    assert set(out[10]) == {1} and 1 in out[50]
    (new,) = ids_near(out[50], 400)
    assert new != 1
    with pytest.raises(ValueError, match="reacquire_gate"):
        DeepSort(**ORIGINAL, reacquire_gate=0.0)
