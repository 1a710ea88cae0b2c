"""Hand-built sequences whose correct tracks are known, run through the full DeepSORT step."""

import numpy as np
import pytest

from spacetrack.tracking import DeepSort, deepsort
from spacetrack.tracking.dynamic import TrackDynamics

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


def _run_on_frames(frames, **overrides):
    """`run`, with a blank 640x480 frame given to each step (the tracker learns the image size)."""
    tracker = DeepSort(**{**ORIGINAL, **overrides})
    blank = np.zeros((480, 640), np.uint8)
    outputs = []
    for dets in frames:
        tlwh = np.array([d[:4] for d in dets], dtype=float).reshape(-1, 4)
        feature = np.array([FEATURES[d[4]] for d in dets]).reshape(-1, 4)
        rows = tracker.step(tlwh, np.full(len(dets), 0.9), feature, image=blank)
        outputs.append({int(r[0]): r[1:] for r in rows})
    return outputs


def test_coast_in_view_leaves_no_box_behind_a_target_that_left_the_image():
    # 8 px/frame to the right, its visible box cut at the right border, gone after frame 14; on frame 14
    # the 8-px sliver no longer matches the track, which coasts on its prediction
    frames = [[(520 + 8 * f, 200, min(40, 640 - 520 - 8 * f), 30, 0)] if f <= 14 else [] for f in range(18)]
    reference = _run_on_frames(frames)
    (box,) = reference[14].values()
    assert box[0] + box[2] > 640  # the reference writes a prediction that reaches outside the image
    out = _run_on_frames(frames, coast_in_view=True)
    assert out[14] == {} and out[13].keys() == {1}
    assert [o.keys() for o in out[:14]] == [o.keys() for o in reference[:14]]


def test_coast_in_view_still_bridges_a_miss_inside_the_image():
    frames = [[(100 + 4 * f, 100, 20, 40, 0)] if f != 10 else [] for f in range(20)]
    out = _run_on_frames(frames, coast_in_view=True)
    assert 1 in out[10] and abs(out[10][1][0] - (100 + 4 * 10)) < 2
    assert [o.keys() for o in out] == [o.keys() for o in _run_on_frames(frames)]


def _swept_target() -> list:
    """A 20 x 20 target moving left 1 px/frame while a 40-px occluder sweeps right over it at 6 px/frame:
    the visible part of its box shrinks from the left (frames 15-17, its centre moving right), it is hidden
    (18-20), then grows back from the left (21-22). Cut boxes look different to the re-ID (feature 1)."""
    frames = []
    for f in range(40):
        x, edge = 300 - f, 200 + 6 * f  # the target's left side; the occluder covers [edge - 40, edge]
        visible = [p for p in range(x, x + 20) if not edge - 40 <= p < edge]
        if not visible:
            frames.append([])
            continue
        left, right = min(visible), max(visible) + 1
        frames.append([(left, 100, right - left, 20, 0 if right - left == 20 else 1)])
    return frames


def test_occluded_area_keeps_the_identity_of_a_target_an_occluder_sweeps_over():
    frames = _swept_target()
    assert [bool(d) for d in frames[14:24]] == [True] * 4 + [False] * 3 + [True] * 3
    settings = dict(reacquire_gate=13.8155, nms_max_overlap=1.0)
    reference = run(frames, **settings)
    # the reference takes the velocity of the cut boxes (rightwards) and loses it: a new identity
    assert set(reference[10]) == {1} and set(reference[25]) == {2}
    out = run(frames, **settings, occluded_area=0.7)
    assert set().union(*out) == {1} and all(set(o) == {1} for o in out[21:])
    assert abs(out[25][1][0] - 275) < 2
    with pytest.raises(ValueError, match="occluded_area"):
        DeepSort(**ORIGINAL, occluded_area=1.0)


def _faded_target(low_score=0.3):
    """A target moving 4 px/frame right, scored 0.9 except on frames 10-19, where the detector scores it
    `low_score`; a second box at `low_score` far from it on every frame (clutter, never a target)."""
    frames = []
    for f in range(30):
        score = low_score if 10 <= f < 20 else 0.9
        frames.append([(100 + 4 * f, 100, 20, 40, 0, score), (400, 300, 20, 40, 1, low_score)])
    return frames


def run_scored(frames, **overrides):
    """Like `run`, with each detection's score as its 6th entry."""
    tracker = DeepSort(**{**ORIGINAL, "min_confidence": 0.5, **overrides})
    outputs = []
    for dets in frames:
        tlwh = np.array([d[:4] for d in dets], dtype=float).reshape(-1, 4)
        feature = np.array([FEATURES[d[4]] for d in dets]).reshape(-1, 4)
        rows = tracker.step(tlwh, np.array([d[5] for d in dets]), feature)
        outputs.append({int(r[0]): r[1:] for r in rows})
    return outputs


def test_low_confidence_keeps_a_track_through_frames_the_detector_scores_low():
    reference = run_scored(_faded_target())
    assert all(not reference[f] for f in range(11, 20))  # below min_confidence: a gap in the output
    out = run_scored(_faded_target(), low_confidence=0.2)
    assert all(out[f].keys() == {1} for f in range(2, 30))  # one track throughout, no gap
    assert abs(out[15][1][0] - (100 + 4 * 15)) < 2  # on the low-scored box, not a drifting prediction
    assert not any(ids_near(o, 400) for o in out)  # a low-scored box alone never starts a track


def test_low_confidence_takes_only_boxes_at_its_floor_and_near_the_track():
    assert all(not run_scored(_faded_target(low_score=0.1), low_confidence=0.2)[f] for f in range(11, 20))
    far = [[(d[0] + (60 if 10 <= f < 20 else 0), *d[1:])  # the low-scored box 60 px off the track
            for d in dets] for f, dets in enumerate(_faded_target())]  # fmt: skip
    assert all(not run_scored(far, low_confidence=0.2)[f] for f in range(11, 20))


@pytest.mark.parametrize("guard", [True, False])
def test_a_low_scored_duplicate_of_a_kept_box_is_not_a_second_target(guard, monkeypatch):
    # target 1 (x 100) matched by its high box; target 2 (x 112) undetected for a frame, whose predicted box
    # the low-scored duplicate of target 1 (x 104: the same object named with another class) overlaps
    if not guard:
        monkeypatch.setattr(deepsort, "LOW_DUPLICATE_IOU", 1.01)
    tracker = DeepSort(**{**ORIGINAL, "min_confidence": 0.5, "low_confidence": 0.2, "nms_max_overlap": 1.0})
    for _ in range(6):
        rows = tracker.step(
            np.array([[100, 100, 20, 40], [112, 100, 20, 40]]), np.array([0.9, 0.9]), FEATURES[:2]
        )
    (second_id,) = [int(r[0]) for r in rows if r[1] == 112]
    tracker.step(np.array([[100, 100, 20, 40], [104, 100, 20, 40]]), np.array([0.9, 0.3]), FEATURES[[0, 0]])
    second = next(t for t in tracker.tracker.tracks if t.track_id == second_id)
    assert second.time_since_update == (1 if guard else 0)  # with the guard it coasts on its prediction


def test_a_negative_low_confidence_is_refused_and_one_at_min_confidence_or_above_changes_nothing():
    with pytest.raises(ValueError, match="tracker.low_confidence must be >= 0 or null, got -0.1"):
        DeepSort(**{**ORIGINAL, "min_confidence": 0.5, "low_confidence": -0.1})

    def plain(outputs):
        return [{k: box.tolist() for k, box in o.items()} for o in outputs]

    reference = plain(run_scored(_faded_target()))
    for value in (0.5, 0.7):  # no detection scores from it up to min_confidence 0.5
        assert plain(run_scored(_faded_target(), low_confidence=value)) == reference


def _blobs_of_faded_target(f):
    """The motion stage's blobs for `_faded_target`'s frame f: the moving target's own box and a stray
    blob far from it."""
    return np.array([(100 + 4 * f, 100, 20, 40), (30, 400, 8, 8)], dtype=float)


def run_with_blobs(frames, blobs, **overrides):
    """Like `run_scored`, passing frame f's `blobs(f)` to `step`."""
    tracker = DeepSort(**{**ORIGINAL, "min_confidence": 0.5, **overrides})
    outputs = []
    for f, dets in enumerate(frames):
        tlwh = np.array([d[:4] for d in dets], dtype=float).reshape(-1, 4)
        feature = np.array([FEATURES[d[4]] for d in dets]).reshape(-1, 4)
        rows = tracker.step(tlwh, np.array([d[5] for d in dets]), feature, blobs=blobs(f))
        outputs.append({int(r[0]): r[1:] for r in rows})
    return outputs, tracker


def test_motion_rescue_keeps_a_track_on_the_blob_of_a_target_the_detector_misses():
    # the detector gives nothing for the target on frames 10-19 (below even a low floor: score 0.1)
    frames = _faded_target(low_score=0.1)
    reference, _ = run_with_blobs(frames, _blobs_of_faded_target)
    assert all(not reference[f] for f in range(11, 20))  # blobs ignored: a gap
    out, _ = run_with_blobs(frames, _blobs_of_faded_target, motion_rescue=True)
    assert all(out[f].keys() == {1} for f in range(2, 30))  # one track throughout
    assert abs(out[15][1][0] - (100 + 4 * 15)) < 1  # on the blob's box
    assert not any(ids_near(o, 30) for o in out)  # a blob alone never starts a track


def test_motion_rescue_leaves_blobs_that_touch_a_detection_to_it():
    # target A (x 100-120) detected throughout; target B beside it (x 122-142) detected on frames 0-7 only
    frames = [
        [(100, 100, 20, 40, 0, 0.9), *([(122, 100, 20, 40, 1, 0.9)] if f < 8 else [])] for f in range(16)
    ]

    def b_frames(blob):
        out, _ = run_with_blobs(frames, lambda f: np.array([blob], float), motion_rescue=True)
        (b,) = ids_near(out[7], 122)
        return [f for f, o in enumerate(out) if b in o]

    assert b_frames((121, 100, 21, 40)) == list(range(2, 16))  # a blob on B alone keeps B's track
    assert b_frames((119, 100, 23, 40)) == list(
        range(2, 9)
    )  # one touching A is A's: B coasts one frame, ends


def _faint_mover_and_faint_parked(score=0.35):
    """A target moving 4 px/frame that the detector scores `score` on every frame, and a parked object
    at the same score: (frames as `run_scored` takes them, per-frame motion flags: the mover's box is
    matched by a blob, the parked one's is not)."""
    frames = [[(100 + 4 * f, 100, 20, 40, 0, score), (400, 300, 20, 40, 1, score)] for f in range(20)]
    return frames, [np.array([True, False])] * len(frames)


def run_flagged(frames, flags, **overrides):
    """Like `run_scored`, with each frame's per-box motion flags and a track-level motion decision."""
    tracker = DeepSort(**{**ORIGINAL, "min_confidence": 0.5, **overrides}, dynamics=TrackDynamics())
    outputs = []
    for dets, moving in zip(frames, flags, strict=True):
        tlwh = np.array([d[:4] for d in dets], dtype=float).reshape(-1, 4)
        feature = np.array([FEATURES[d[4]] for d in dets]).reshape(-1, 4)
        rows = tracker.step(tlwh, np.array([d[5] for d in dets]), feature, dynamic=moving)
        outputs.append({int(r[0]): r[1:] for r in rows})
    return outputs


def test_motion_confirm_tracks_a_low_scored_box_that_moves_and_not_one_that_does_not():
    frames, flags = _faint_mover_and_faint_parked()
    assert not any(run_flagged(frames, flags))  # below min_confidence 0.5: nothing is tracked
    out = run_flagged(frames, flags, motion_confirm=0.3)
    assert all(len(out[f]) == 1 and ids_near(out[f], 100 + 4 * f) for f in range(3, 20))  # the mover only
    assert not any(ids_near(o, 400) for o in out)  # the parked box at the same score stays out
    # its floor holds: a mover scored under it is not confirmed, and low_confidence keeps its role
    assert not any(run_flagged(*_faint_mover_and_faint_parked(score=0.25), motion_confirm=0.3))
    assert not any(run_flagged(frames, flags, low_confidence=0.3))  # low boxes never start a track


def test_motion_confirm_without_motion_flags_is_refused_and_none_changes_nothing():
    with pytest.raises(
        ValueError, match="motion_confirm=0.3 needs each box's motion flag.*dynamic_filter=track"
    ):
        DeepSort(**{**ORIGINAL, "min_confidence": 0.5, "motion_confirm": 0.3})
    for bad in (-0.1, True):
        with pytest.raises(ValueError, match="tracker.motion_confirm must be >= 0 or null"):
            DeepSort(**{**ORIGINAL, "min_confidence": 0.5, "motion_confirm": bad}, dynamics=TrackDynamics())
    frames, flags = _faint_mover_and_faint_parked(score=0.9)

    def plain(outputs):
        return [{k: box.tolist() for k, box in o.items()} for o in outputs]

    reference = plain(run_flagged(frames, flags))
    assert reference[5]  # both boxes above min_confidence: the mover is tracked either way
    assert plain(run_flagged(frames, flags, motion_confirm=0.3)) == reference


def test_a_confirmed_box_that_no_stage_matches_goes_to_its_track_by_overlap_before_starting_one():
    # a target tracked at 0.9 (appearance 0) for 10 frames, missed on frame 10, then scored 0.35 with an
    # appearance the gallery rejects (1): only box overlap ties it to its track, which has gone unmatched
    frames = [[(100 + 4 * f, 100, 20, 40, 0 if f < 10 else 1, 0.9 if f < 10 else 0.35)] if f != 10 else []
              for f in range(16)]  # fmt: skip
    flags = [np.ones(len(dets), bool) for dets in frames]
    out = run_flagged(frames, flags, motion_confirm=0.3, low_confidence=0.3)
    assert {k for o in out for k in o} == {1}  # one identity throughout
    assert all(ids_near(out[f], 100 + 4 * f) == [1] for f in range(11, 16))
