import numpy as np
import pytest

from spacetrack.motion import FiveFrameDifference, ThreeFrameDifference, TwoFrameDifference
from spacetrack.motion.difference import binarise


def test_binarise_threshold_is_inclusive_and_adaptive():
    diff = np.array([[19, 20, 21, 100]], dtype=np.uint8)
    assert binarise(diff, alpha=0.0, threshold=20).tolist() == [[0, 255, 255, 255]]
    # mean 40 lifts the level to 60
    assert binarise(diff, alpha=1.0, threshold=20).tolist() == [[0, 0, 0, 255]]


@pytest.mark.parametrize(
    ("cls", "latency"), [(TwoFrameDifference, 0), (ThreeFrameDifference, 1), (FiveFrameDifference, 2)]
)
def test_square_moving_over_black_field(scene, run, cls, latency):
    frames, truth = scene(8)
    masks = run(cls(), frames)
    assert cls.latency == latency
    span = cls.span
    assert sorted(masks) == list(range(span - 1 - latency, 8 - latency))
    for t, mask in masks.items():
        if cls is TwoFrameDifference:
            # both the new and the old place: the 'bilateral thick outline'
            assert np.array_equal(mask, truth[t] | truth[t - 1])
        else:
            assert np.array_equal(mask, truth[t])


@pytest.mark.parametrize("cls", [TwoFrameDifference, ThreeFrameDifference, FiveFrameDifference])
def test_global_flash_is_not_motion_after_adaptive_threshold(scene, run, cls):
    frames, _ = scene(9, velocity=(0, 0), flash_at=4)
    adaptive = run(cls(alpha=1.0, threshold=20), frames)
    fixed = run(cls(alpha=0.0, threshold=20), frames)
    assert not any(m.any() for m in adaptive.values())
    # the same flash with a fixed threshold lights up the whole frame
    assert max(m.mean() for m in fixed.values()) > 0.9


def test_target_that_stops_leaves_no_motion(scene, run):
    frames, _ = scene(12, stop_at=5)
    masks = run(FiveFrameDifference(), frames)
    assert masks[4].sum() > 0
    # from frame 7 on, all five frames around t show the square in the same place
    assert all(masks[t].sum() == 0 for t in range(7, 10))


def test_static_star_is_never_motion(scene, run):
    frames, _ = scene(10, stars=((5, 5), (90, 60)))
    for cls in (TwoFrameDifference, ThreeFrameDifference, FiveFrameDifference):
        for mask in run(cls(), frames).values():
            assert not mask[5, 5] and not mask[60, 90]


def test_bad_parameters():
    with pytest.raises(ValueError, match="threshold"):
        FiveFrameDifference(threshold=0)
    with pytest.raises(ValueError, match="alpha"):
        TwoFrameDifference(alpha=-1)


def test_exposure_step_is_not_motion_when_exposure_is_matched(scene, run):
    frames, _ = scene(9, velocity=(0, 0))
    # exposure up by a quarter from frame 4 on (below saturation: clipped pixels cannot be matched)
    frames[4:] = [np.round(f * 1.25).astype(np.uint8) for f in frames[4:]]
    assert not any(m.any() for m in run(FiveFrameDifference(match_exposure=True), frames).values())
    # unmatched, the square brightens by 50 grey levels: motion
    assert any(m.any() for m in run(FiveFrameDifference(), frames).values())
