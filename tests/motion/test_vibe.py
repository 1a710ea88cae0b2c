import numpy as np
import pytest

from spacetrack.motion import ViBe


def test_square_entering_a_black_field_is_exactly_foreground(scene, run):
    # the square enters after the first frame, so the model holds no trace of it (no ghost)
    frames, truth = scene(8, start=(2, 20))
    frames[0] = scene(1, start=(200, 200), size=0)[0][0]
    masks = run(ViBe(), frames)
    assert sorted(masks) == list(range(8))
    assert not masks[0].any()
    for t in range(1, 8):
        assert np.array_equal(masks[t], truth[t])


def test_ghost_of_first_frame_dissolves_from_its_border(scene, run):
    frames, truth = scene(200, velocity=(0, 0), stop_at=0)
    # the square was in the first frame only: its old place is a ghost that neighbours eat away
    frames[1:] = scene(199, start=(200, 200), size=0, seed=1)[0]
    masks = run(ViBe(), frames)
    early, late = masks[1][truth[0]].sum(), masks[199][truth[0]].sum()
    # its rim sampled the dark field at initialisation, so only the 6x6 interior starts as ghost
    assert early == 36
    assert late < early


def test_target_that_stops_is_absorbed_into_the_background(scene, run):
    frames, truth = scene(150, stop_at=3, size=6)
    stopped = truth[3]
    masks = run(ViBe(absorb_after=60), frames)
    assert masks[4][stopped].all()
    assert masks[59][stopped].all()
    assert not masks[149][stopped].any()
    # without absorption a stopped bright target stays foreground: nothing around it looks like it
    assert run(ViBe(absorb_after=0), frames)[149][stopped].all()


def test_absorbing_every_frame_takes_a_stopped_target_in_min_matches_frames(scene, run):
    frames, truth = scene(40, stop_at=3, size=6)
    stopped = truth[3]
    # foreground from frame 3, absorbed at its 10th frame (12), which writes a sample of its own and one
    # into a neighbour (the same value inside the square): background by frame 14 at the latest
    masks = run(ViBe(absorb_after=10, absorb_subsampling=1), frames)
    assert all(masks[t][stopped].all() for t in range(3, 13))
    assert not masks[14][stopped].any()
    # at the default rate of 1/16 most of it is still foreground then
    assert run(ViBe(absorb_after=10), frames)[14][stopped].mean() > 0.5
    with pytest.raises(ValueError, match="absorb_subsampling"):
        ViBe(absorb_subsampling=0)


def test_static_star_and_flash_free_field(scene, run):
    frames, _ = scene(30, stars=((5, 5), (90, 60)), size=0)
    masks = run(ViBe(), frames)
    assert not any(m.any() for m in masks.values())


def test_colour_model_sees_a_change_of_hue_that_grey_misses():
    red, green = np.array([200, 60, 0], np.uint8), np.array([103, 100, 120], np.uint8)
    first = np.zeros((20, 20, 3), np.uint8)
    first[...] = red
    second = first.copy()
    second[5:10, 5:10] = green  # about the same grey level as red
    grey, colour = ViBe(), ViBe(colour=True)
    for detector in (grey, colour):
        detector.apply(first)
    assert not grey.apply(second).any()
    assert colour.apply(second)[5:10, 5:10].all()


def test_reference_parameters_and_bad_values():
    vibe = ViBe()
    assert (vibe.num_samples, vibe.radius, vibe.min_matches, vibe.subsampling) == (20, 20, 2, 16)
    with pytest.raises(ValueError, match="min_matches"):
        ViBe(min_matches=21)
    with pytest.raises(ValueError, match="subsampling"):
        ViBe(subsampling=0)


def test_exposure_step_is_not_foreground_when_exposure_is_matched(scene, run):
    frames, _ = scene(12, velocity=(0, 0))
    # exposure up by a quarter from frame 6 on (below saturation: clipped pixels cannot be matched)
    frames[6:] = [np.round(f * 1.25).astype(np.uint8) for f in frames[6:]]
    assert not any(m.any() for m in run(ViBe(match_exposure=True), frames).values())
    assert run(ViBe(), frames)[6].any()


@pytest.mark.parametrize("colour", [False, True])
def test_two_pass_decision_equals_counting_every_sample(colour):
    rng = np.random.default_rng(4)
    shape = (30, 40, 3) if colour else (30, 40)
    vibe = ViBe(colour=colour, radius=15)
    vibe.apply(rng.integers(0, 256, shape, dtype=np.uint8))
    image = rng.integers(0, 256, shape, dtype=np.uint8)
    # samples close to the image at some pixels, scattered far at others, so both answers occur
    spread = rng.choice([8, 30, 90], size=shape)
    noise = rng.uniform(-1, 1, vibe._model.shape) * spread
    vibe._model = np.clip(image + noise, 0, 255).astype(np.uint8)
    diff = vibe._model.astype(int) - image
    dist2 = (diff**2).sum(axis=-1) if colour else diff**2
    brute = (dist2 < 15**2).sum(axis=0) < vibe.min_matches
    assert 0 < brute.sum() < brute.size
    np.testing.assert_array_equal(vibe._foreground(image) > 0, brute)
