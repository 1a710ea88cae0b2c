"""The track-level dynamic decision and the camera motion in the tracker, on hand-made sequences."""

import logging

import numpy as np
import pytest

from spacetrack.tracking import DeepSort
from spacetrack.tracking.dynamic import TrackDynamics

SORT = dict(
    max_cosine_distance=None, nn_budget=None, max_iou_distance=0.7, max_age=30, n_init=3, min_confidence=0.3,
    nms_max_overlap=1.0,
)  # fmt: skip
H, W = 256, 256


def starfield(seed=0):
    """A (H + 200, W + 200) uint8 field of bright points: texture for the phase correlation."""
    rng = np.random.default_rng(seed)
    field = np.zeros((H + 200, W + 200), np.uint8)
    ys, xs = rng.integers(0, field.shape[0], 400), rng.integers(0, field.shape[1], 400)
    field[ys, xs] = 255
    field[np.clip(ys + 1, 0, None) % field.shape[0], xs] = 180
    return field


def view(field, offset):
    """The camera's (H, W) window on `field` when the scene has moved by `offset` (x, y whole pixels)."""
    x, y = 150 - offset[0], 100 - offset[1]
    return np.ascontiguousarray(field[y : y + H, x : x + W])


def run(frames, dynamics=None, camera_motion=False, **overrides):
    """frames: per-frame (boxes (N, 4) tlwh, blob flags (N,) or None, image or None). Returns [{id: tlwh}]."""
    tracker = DeepSort(**{**SORT, **overrides}, camera_motion=camera_motion, dynamics=dynamics)
    outputs = []
    for boxes, flags, image in frames:
        boxes = np.asarray(boxes, float).reshape(-1, 4)
        rows = tracker.step(boxes, np.full(len(boxes), 0.9), dynamic=flags, image=image)
        outputs.append({int(r[0]): r[1:] for r in rows})
    return outputs


def test_a_parked_object_under_a_slewing_camera_stays_static_and_is_one_track():
    # The camera slews 3 px/frame: the parked object drifts across the image with the stars. Its masks
    # flicker on it in two frames of 40; a real mover at 2 px/frame against the scene crosses the field.
    field, frames = starfield(), []
    for f in range(40):
        offset = (3 * f, 0)
        parked = (40 + offset[0], 60, 16, 16)
        mover = (40 + offset[0] + 2 * f, 150, 16, 16)
        flags = np.array([f in (5, 6), False])  # no mask on the mover either: its trajectory must tell
        frames.append(([parked, mover], flags, view(field, offset)))
    dynamics = TrackDynamics()
    out = run(frames, dynamics=dynamics, camera_motion=True)
    shown = set().union(*out)
    assert len(shown) == 1  # only the mover is ever output
    (mover_id,) = shown
    assert all(abs(box[1] - 150) < 3 for o in out for box in o.values())
    assert out[-1].keys() == {mover_id}
    # without the camera's shift the parked object seems to move 3 px/frame and becomes a track
    fooled = run(frames, dynamics=TrackDynamics(), camera_motion=False)
    assert len(set().union(*fooled)) == 2


def test_a_dim_mover_without_masks_becomes_dynamic_by_its_trajectory():
    frames = [([(50 + 1.0 * f, 80, 12, 12)], np.array([False]), None) for f in range(30)]
    out = run(frames, dynamics=TrackDynamics(min_displacement=6.0, min_displacement_height=0.0, window=5))
    first = min(f for f, o in enumerate(out) if o)
    # median of the last 5 centres lags 2 frames: 6 px against the first centre at frame 8
    assert first == 8
    assert all(o.keys() == {1} for o in out[first:])


def test_a_target_that_stops_keeps_its_track():
    # moves 3 px/frame with masks for 15 frames, then stands still without any mask for 30 frames
    xs = [50 + 3 * min(f, 15) for f in range(45)]
    frames = [([(x, 80, 12, 12)], np.array([f < 15]), None) for f, x in enumerate(xs)]
    out = run(frames, dynamics=TrackDynamics())
    assert out[2].keys() == {1}  # dynamic by its masks from its second hit, shown from n_init on
    assert all(o.keys() == {1} for o in out[2:])  # stopped frames 15-44 included


def test_a_parked_object_with_masks_only_flickering_is_never_output():
    flags = np.zeros(60, bool)
    flags[[3, 20, 40]] = True  # single-frame flickers: never 2 of the last 5 hits
    frames = [([(100, 100, 20, 20)], flags[f : f + 1], None) for f in range(60)]
    assert not any(run(frames, dynamics=TrackDynamics()))


def test_a_still_camera_gives_exactly_the_tracks_of_no_compensation():
    rng = np.random.default_rng(1)
    field, frames = starfield(1), []
    for f in range(40):
        boxes = [
            (30 + 2 * f + rng.normal(0, 0.5), 40, 15, 15),
            (200 - 2 * f, 42 + rng.normal(0, 0.5), 15, 15),
        ]
        frames.append((boxes, None, view(field, (0, 0))))
    plain = run(frames, camera_motion=False)
    for mode in (True, "auto"):
        compensated = run(frames, camera_motion=mode)
        assert [o.keys() for o in compensated] == [o.keys() for o in plain]
        for a, b in zip(compensated, plain, strict=True):
            for k in a:
                np.testing.assert_array_equal(a[k], b[k])


def test_a_frame_without_texture_gets_no_shift_and_is_logged_once(caplog):
    field = starfield()
    black = np.zeros((H, W), np.uint8)
    images = [view(field, (0, 0)), black, black, view(field, (0, 0)), black]
    frames = [([(60, 60, 15, 15)], None, image) for image in images]
    with caplog.at_level(logging.WARNING, logger="spacetrack.tracking.camera_motion"):
        out = run(frames, camera_motion=True, n_init=1)
    warnings = [r for r in caplog.records if "no texture" in r.message]
    assert len(warnings) == 1 and "frame 2" in warnings[0].message
    assert all(np.allclose(o[1], (60, 60, 15, 15), atol=1e-6) for o in out[1:])  # no shift applied


@pytest.mark.parametrize(
    ("key", "value"),
    [("window", 0), ("window", -3), ("min_blob_ratio", 1.5), ("min_blob_ratio", -0.1), ("min_blob_hits", 0),
     ("min_displacement", 0.0), ("min_displacement_height", -1.0), ("min_displacement_camera", -0.1),
     ("min_share_of_best", 1.5)],
)  # fmt: skip
def test_out_of_range_settings_are_an_error_naming_the_key(key, value):
    with pytest.raises(ValueError, match=rf"dynamic_track\.{key} must be .*got {value}"):
        TrackDynamics(**{key: value})


def test_output_box_detection_writes_the_matched_box_and_the_state_on_a_missed_frame():
    frames = [([(100 + 2 * f + (0.7 if f % 2 else -0.7), 100, 20, 20)], None, None) for f in range(6)]
    frames.append(([], None, None))
    state = run(frames)
    detection = run(frames, output_box="detection")
    for f in range(2, 6):
        np.testing.assert_array_equal(detection[f][1], frames[f][0][0])
        assert not np.allclose(state[f][1], frames[f][0][0])  # the reference writes the Kalman state
    np.testing.assert_array_equal(detection[6][1], state[6][1])  # no match: the predicted state


def test_an_unknown_camera_motion_mode_is_an_error():
    with pytest.raises(ValueError, match="tracker.camera_motion must be false, true or auto, got 'on'"):
        DeepSort(**SORT, camera_motion="on")


def test_under_a_moving_camera_masks_on_a_parked_object_no_longer_make_it_dynamic():
    # The camera slews from the first frame; the motion masks light up on the parked object in its first
    # frames (the motion stage has not caught up with the slew yet). The trajectory says it is parked.
    field, frames = starfield(), []
    for f in range(30):
        offset = (3 * f, 0)
        frames.append(([(40 + offset[0], 60, 16, 16)], np.array([f < 8]), view(field, offset)))
    assert not set().union(*run(frames, dynamics=TrackDynamics(), camera_motion="auto"))
    trusting = run(frames, dynamics=TrackDynamics(blobs_when_camera_moves=True), camera_motion="auto")
    assert set().union(*trusting)  # trusting the masks, it is output


def test_a_parked_object_cut_down_by_a_passing_mover_stays_static():
    # A mover goes up through a parked 20x24 object; while it passes, the parked box is cut from below
    # (its visible part shrinks to 3x3 px and grows back), which moves the box centre by up to 8 px.
    # No blob on the parked object: only its trajectory could make it dynamic, and its edges do not move
    # the same way.
    frames = []
    for f in range(40):
        mover = (112, 230 - 4 * f, 26, 60)
        cut = int(np.clip(24 - abs(f - 18) * 3, 0, 21))  # rows hidden from below, 0 .. 21
        parked = (113, 160, 20 - (cut * 17) // 21, 24 - cut)
        frames.append(([mover, parked], np.array([True, False]), None))
    out = run(frames, dynamics=TrackDynamics())
    shown = set().union(*out)
    assert len(shown) == 1 and all(abs(box[0] - 112) < 2 for o in out for box in o.values())


def test_a_box_that_translates_moves_by_the_shift_its_edges_share():
    from spacetrack.tracking.dynamic import shared_shift

    anchor = np.array([10.0, 10.0, 30.0, 40.0])  # x1, y1, x2, y2
    assert shared_shift(anchor, anchor + [5, -3, 5, -3]) == pytest.approx(np.hypot(5, 3))
    assert shared_shift(anchor, anchor + [2, 0, 6, 0]) == pytest.approx(2.0)  # grew while moving right
    assert shared_shift(anchor, [10, 20, 30, 40]) == 0.0  # cut from the top: the centre moves 5 px
    assert shared_shift(anchor, [12, 12, 28, 38]) == 0.0  # shrank on every side


def test_an_edge_on_the_image_border_leaves_the_other_edge_to_tell_the_motion():
    from spacetrack.tracking.dynamic import free_edges, shared_shift

    anchor = np.array([300.0, 0.0, 306.0, 1.0])  # a target coming into view at the top: 6x1 px
    now = np.array([296.0, 0.0, 306.0, 13.0])  # 12 px further in, its top edge still on the border
    assert shared_shift(anchor, now) == 0.0  # every edge counted: the top one pins it
    free = free_edges([296, 0, 10, 13], (640, 480)) & free_edges([300, 0, 6, 1], (640, 480))
    assert free.tolist() == [True, False, True, True]
    assert shared_shift(anchor, now, free) == pytest.approx(12.0)
    assert free_edges([0, 0, 640, 480], None).all()


def test_a_parked_object_under_a_long_slew_with_a_drifting_shift_estimate_stays_static():
    # The camera slews 2 px/frame for 150 frames; the estimated shift falls 4 % short, so in scene
    # coordinates the parked object drifts 12 px by the end. A mover at 1 px/frame against the scene still
    # becomes dynamic.
    for share, parked_dynamic in ((0.1, False), (0.0, True)):
        dynamics = TrackDynamics(min_displacement_camera=share)
        parked, mover = dynamics.new_evidence(), dynamics.new_evidence()
        for f in range(150):
            true, estimated = np.array([2.0 * f, 0.0]), np.array([1.92 * f, 0.0])
            dynamics.observe(parked, np.r_[200 + true, 16, 16], estimated, False, camera_moving=True)
            dynamics.observe(mover, np.r_[300 + true + [f, 0], 16, 16], estimated, False, camera_moving=True)
        assert parked.dynamic is parked_dynamic
        assert mover.dynamic


def test_the_configured_motion_confirm_needs_the_track_filter_and_appearance_for_what_it_confirms():
    from spacetrack.config import compose_config
    from spacetrack.pipeline.runner import build_tracker

    def build(*overrides):
        return build_tracker(compose_config("track", list(overrides)))

    assert build("tracker.motion_confirm=0.3").motion_confirm == 0.3  # reid_min_score 0.3, filter track
    with pytest.raises(ValueError, match=r"motion_confirm=0.2 is below reid_min_score=0.3"):
        build("tracker.motion_confirm=0.2")
    assert build("tracker.motion_confirm=0.2", "reid_min_score=0.2").motion_confirm == 0.2
    with pytest.raises(ValueError, match="needs each box's motion flag.*dynamic_filter=track"):
        build("tracker.motion_confirm=0.3", "dynamic_filter=frame")
