"""Offline post-processing: backfill of the frames before a track's first output, gap interpolation, GSI."""

import numpy as np
import pytest

from spacetrack.tracking.offline import (
    OfflineSettings,
    backfill,
    gaussian_smooth,
    interpolate_gaps,
    post_process,
)


def track(tid, frames, x0=10.0, vx=2.0):
    """Rows of one target moving right at vx px/frame, 8x6 px."""
    frames = np.asarray(frames, dtype=float)
    return np.column_stack(
        [frames, np.full(len(frames), tid), x0 + vx * (frames - 1), np.full(len(frames), 20.0),
         np.full(len(frames), 8.0), np.full(len(frames), 6.0)]
    )  # fmt: skip


def test_gap_is_filled_linearly_and_long_gaps_are_left():
    rows = np.concatenate([track(1, [1, 2, 3, 7, 8]), track(2, [1, 2, 30])])
    out = interpolate_gaps(rows, max_gap=5)
    one = out[out[:, 1] == 1]
    np.testing.assert_array_equal(one[:, 0], [1, 2, 3, 4, 5, 6, 7, 8])
    # the target moves linearly, so the interpolated boxes are exactly its boxes
    np.testing.assert_allclose(one, track(1, range(1, 9)))
    two = out[out[:, 1] == 2]
    np.testing.assert_array_equal(two[:, 0], [1, 2, 30])  # a 27-frame gap is over max_gap 5


def test_gap_of_exactly_max_gap_is_filled_and_zero_fills_nothing():
    rows = track(1, [1, 5])  # 3 missing frames
    assert len(interpolate_gaps(rows, max_gap=3)) == 5
    assert len(interpolate_gaps(rows, max_gap=2)) == 2
    np.testing.assert_array_equal(post_process(rows, None, OfflineSettings(backfill=False, max_gap=0)), rows)


def test_backfill_gives_a_track_its_matched_frames_before_its_first_output():
    online = np.concatenate([track(1, range(4, 10)), track(2, range(6, 10))])
    matched = np.concatenate(
        [track(1, range(1, 10)), track(2, range(3, 10)), track(3, [1, 2])]  # 3: never output (tentative)
    )
    out = backfill(online, matched)
    np.testing.assert_array_equal(out[out[:, 1] == 1][:, 0], np.arange(1, 10))
    np.testing.assert_array_equal(out[out[:, 1] == 2][:, 0], np.arange(3, 10))
    assert 3 not in out[:, 1]  # a track never output stays out
    # sorted by frame, then id; no duplicate (frame, id)
    assert np.all(np.diff(out[:, 0]) >= 0)
    assert len({(f, i) for f, i in out[:, :2]}) == len(out)


def test_backfill_never_moves_an_online_row():
    online = track(1, range(4, 8))
    matched = track(1, range(1, 8), x0=50.0)  # other boxes on the online frames
    out = backfill(online, matched)
    np.testing.assert_allclose(out[out[:, 0] >= 4], online)


def test_smoothing_pulls_a_noisy_track_towards_its_trend():
    rng = np.random.default_rng(0)
    clean = track(1, range(1, 61))
    noisy = clean.copy()
    noisy[:, 2:4] += rng.normal(0, 1.5, size=(60, 2))
    smooth = gaussian_smooth(noisy[:, 0], noisy[:, 2:6], length_scale=10.0)
    err_before = np.abs(noisy[:, 2:4] - clean[:, 2:4]).mean()
    err_after = np.abs(smooth[:, :2] - clean[:, 2:4]).mean()
    assert err_after < 0.6 * err_before


def test_post_process_backfills_then_interpolates():
    online = track(1, [5, 6, 9, 10])
    matched = track(1, [2, 3, 4, 5, 6, 9, 10])
    out = post_process(online, matched, OfflineSettings(backfill=True, max_gap=4))
    np.testing.assert_array_equal(out[:, 0], np.arange(2, 11))


@pytest.mark.parametrize("kwargs", [{"max_gap": -1}, {"max_gap": 2.5}, {"smooth_frames": 0}])
def test_bad_settings_are_refused_with_the_value(kwargs):
    with pytest.raises(ValueError, match=str(next(iter(kwargs.values())))):
        OfflineSettings(**kwargs)


def test_rows_of_the_wrong_shape_are_refused():
    with pytest.raises(ValueError, match=r"\(N, 6\)"):
        interpolate_gaps(np.zeros((3, 4)), max_gap=2)


def test_empty_rows_pass_through():
    assert post_process(np.zeros((0, 6)), np.zeros((0, 6)), OfflineSettings()).shape == (0, 6)


def test_the_tracker_lists_a_tentative_track_as_matched_before_it_is_output():
    from spacetrack.tracking.deepsort import DeepSort

    tracker = DeepSort(max_cosine_distance=None, nn_budget=None, max_iou_distance=0.7, max_age=30,
                       n_init=3, min_confidence=0.0, nms_max_overlap=1.0)  # fmt: skip
    box = np.array([[10.0, 20.0, 8.0, 6.0]])
    for frame in range(1, 4):
        out = tracker.step(box + [2.0 * frame, 0, 0, 0], np.ones(1))
        matched = tracker.matched_tracks()
        assert len(matched) == 1 and matched[0, 0] == 1
        np.testing.assert_allclose(matched[0, 1:], box[0] + [2.0 * frame, 0, 0, 0])  # the detection's box
        assert len(out) == (1 if frame == 3 else 0)  # output from the n_init-th hit on
