import cv2
import numpy as np
import pytest

from spacetrack.motion import FiveFrameDifference, ViBe
from spacetrack.motion.compensation import SceneShift, shift_image, warp_shift


def test_shift_image_moves_content_and_fills_the_rest():
    image = np.arange(12, dtype=np.uint8).reshape(3, 4)
    out = shift_image(image, 1, -1, np.uint8(99))
    np.testing.assert_array_equal(out, [[99, 4, 5, 6], [99, 8, 9, 10], [99, 99, 99, 99]])
    stack = np.stack([image, image + 50])
    np.testing.assert_array_equal(shift_image(stack, 1, -1, 99, axis=1)[1], np.where(out == 99, 99, out + 50))
    assert shift_image(image, 0, 0, 0) is image
    assert (shift_image(image, 5, 0, 7) == 7).all()


def test_warp_shift_moves_by_fractions_and_fills_from_the_fill_image():
    image = np.zeros((4, 6), np.uint8)
    image[:, 2] = 200
    out = warp_shift(image, 0.5, 0.0, np.full((4, 6), 7, np.uint8))
    assert out[1, 2] == 100 and out[1, 3] == 100 and out[1, 1] == 0
    assert (warp_shift(image, 2.0, 0.0, np.full((4, 6), 7, np.uint8))[:, :2] == 7).all()


def _star_field(num_frames: int, step: tuple[int, int], shape=(256, 256), seed=0) -> list[np.ndarray]:
    """A field of 3x3 stars drifting by `step` whole pixels per frame (a slewing camera)."""
    rng = np.random.default_rng(seed)
    sky = np.full((shape[0] * 2, shape[1] * 2), 10.0)
    for y, x in zip(
        rng.integers(2, sky.shape[0] - 2, 300), rng.integers(2, sky.shape[1] - 2, 300), strict=True
    ):
        sky[y - 1 : y + 2, x - 1 : x + 2] = rng.uniform(80, 250)
    frames = []
    for t in range(num_frames):
        y0, x0 = 40 - step[1] * t, 40 - step[0] * t
        noisy = sky[y0 : y0 + shape[0], x0 : x0 + shape[1]] + rng.normal(0, 2, shape)
        frames.append(np.clip(noisy, 0, 255).astype(np.uint8))
    return frames


def test_scene_shift_accumulates_the_slew():
    shift = SceneShift()
    offsets = [shift.update(f) for f in _star_field(6, (2, -1))]
    np.testing.assert_allclose(offsets, [(2 * t, -t) for t in range(6)], atol=0.15)
    shift.reset()
    assert shift.update(np.zeros((8, 8), np.uint8)) == (0, 0)
    with pytest.raises(ValueError, match="tile"):
        SceneShift(tile=4)


def _still_field_with_a_target(num_frames: int) -> list[np.ndarray]:
    """A still star field crossed by a bright 24-pixel target moving 3 pixels a frame."""
    frames = _star_field(num_frames, (0, 0), seed=1)
    for t, frame in enumerate(frames):
        frame[100:124, 20 + 3 * t : 44 + 3 * t] = 220
    return frames


def test_a_still_camera_stays_still_while_a_target_crosses_it():
    frames = _still_field_with_a_target(40)
    shift = SceneShift()
    assert [shift.update(f) for f in frames] == [(0.0, 0.0)] * len(frames)
    # every estimate summed: the target's pull adds up (to 0.12-0.2+ px over the 40 frames, by how this
    # machine's OpenCV computes the phase correlation), where min_step keeps exactly 0
    drifting = SceneShift(min_step=0)
    assert max(abs(v) for f in frames for v in drifting.update(f)) > 0.05
    with pytest.raises(ValueError, match="min_step"):
        SceneShift(min_step=-1)


@pytest.mark.parametrize("cls", [FiveFrameDifference, ViBe])
def test_compensation_changes_nothing_for_a_still_camera(run, cls):
    frames = _still_field_with_a_target(40)
    plain = run(cls(), frames)
    compensated = run(cls(compensate=True), frames)
    assert plain.keys() == compensated.keys()
    assert all((plain[k] == compensated[k]).all() for k in plain)


@pytest.mark.parametrize("cls", [FiveFrameDifference, ViBe])
def test_compensation_keeps_a_slewing_star_field_still(run, cls):
    frames = _star_field(12, (2, 1))
    plain = run(cls(), frames)
    compensated = run(cls(compensate=True), frames)
    assert max(m.mean() for m in plain.values()) > 0.01
    assert max(m.mean() for m in compensated.values()) < 0.0005


def test_sub_pixel_slew_of_blurred_stars_is_not_motion_once_compensated(run):
    # stars on a 4x finer grid moved by (6, 2) fine pixels a frame: a slew of (1.5, 0.5) pixels
    rng = np.random.default_rng(2)
    fine = np.zeros((96 * 4 * 2, 128 * 4 * 2), np.float32)
    fine[rng.integers(0, fine.shape[0], 400), rng.integers(0, fine.shape[1], 400)] = 255 * 16
    fine = cv2.GaussianBlur(fine, (0, 0), 4.0)
    frames = []
    for t in range(10):
        window = fine[200 - 2 * t : 200 - 2 * t + 384, 200 - 6 * t : 200 - 6 * t + 512]
        coarse = cv2.resize(window, (128, 96), interpolation=cv2.INTER_AREA) + rng.normal(0, 1.5, (96, 128))
        frames.append(np.clip(coarse + 8, 0, 255).astype(np.uint8))
    plain = run(FiveFrameDifference(threshold=10), frames)
    compensated = run(FiveFrameDifference(threshold=10, compensate=True), frames)
    moving_plain = sum(m.sum() for m in plain.values())
    assert moving_plain > 1000
    assert sum(m.sum() for m in compensated.values()) < moving_plain / 20


def test_the_fusion_measures_each_frame_once_for_both_parts_in_turn_or_in_parallel(monkeypatch):
    from spacetrack.motion import Fusion

    frames = _star_field(14, (2, 1))
    for t, frame in enumerate(frames):
        frame[60:80, 30 + 4 * t : 50 + 4 * t] = 200  # a target too

    def fusion(**kwargs):
        return Fusion(
            difference=FiveFrameDifference(compensate=True), background=ViBe(compensate=True), **kwargs
        )

    separate = fusion()
    separate.background.scene_shift = SceneShift()  # each part measures on its own, as before sharing
    calls = []
    measure = SceneShift._measure
    monkeypatch.setattr(SceneShift, "_measure", lambda self, grey: calls.append(1) or measure(self, grey))
    expected = [separate.apply(f) for f in frames]
    assert len(calls) == 2 * len(frames)
    for shared in (fusion(), fusion(parallel=True)):
        assert shared.background.scene_shift is shared.difference.scene_shift
        calls.clear()
        masks = [shared.apply(f) for f in frames]
        assert len(calls) == len(frames)
        assert all(
            (a is None and b is None) or np.array_equal(a, b) for a, b in zip(masks, expected, strict=True)
        )
        assert sum(m.sum() for m in masks if m is not None) > 0  # the target is found
        shared.close()


def test_a_shared_estimator_refuses_frames_out_of_step():
    shift = SceneShift()
    frames = _star_field(3, (1, 0))
    assert shift.update(frames[0], 0) == shift.update(frames[0], 0) == (0.0, 0.0)
    first = shift.update(frames[1], 1)
    assert shift.update(frames[1], 1) == first
    with pytest.raises(ValueError, match="frame 3"):
        shift.update(frames[2], 3)


@pytest.mark.parametrize("cls", [FiveFrameDifference, ViBe])
def test_auto_leaves_a_still_camera_alone_and_probes_one_frame_in_ten(run, cls, monkeypatch):
    frames = _still_field_with_a_target(40)
    calls = []
    step = SceneShift._step
    monkeypatch.setattr(SceneShift, "_step", lambda self, *args: calls.append(1) or step(self, *args))
    auto = cls(compensate="auto")
    masks = run(auto, frames)
    assert not auto.scene_shift.moving and len(calls) == 3  # probes at frames 10, 20, 30
    plain = run(cls(), frames)
    assert all((plain[k] == masks[k]).all() for k in plain)


@pytest.mark.parametrize("cls", [FiveFrameDifference, ViBe])
def test_auto_compensates_a_slewing_camera_from_its_first_probe_on(run, cls):
    frames = _star_field(36, (1, 1))
    auto = cls(compensate="auto")
    masks = run(auto, frames)
    assert auto.scene_shift.moving
    plain = run(cls(), frames)
    late = [k for k in masks if k >= 16]  # a few frames after the probe at frame 10 found the slew
    assert max(plain[k].mean() for k in late) > 0.01
    assert max(masks[k].mean() for k in late) < 0.0005


def test_compensate_takes_false_true_or_auto():
    with pytest.raises(ValueError, match="'sometimes'"):
        FiveFrameDifference(compensate="sometimes")
    with pytest.raises(ValueError, match="probe_every"):
        SceneShift(probe_every=-1)


def test_a_first_probe_finds_a_slew_on_the_second_frame_and_leaves_a_still_camera_alone():
    slewing = _star_field(14, (2, 0))
    early, late = SceneShift(probe_every=10, first_probe=True), SceneShift(probe_every=10)
    with_probe = [early.update(f) for f in slewing]
    without = [late.update(f) for f in slewing]
    np.testing.assert_allclose(with_probe, [(2 * t, 0) for t in range(14)], atol=0.3)  # from frame 2 on
    assert all(o == (0.0, 0.0) for o in without[:10])  # the plain schedule waits for frame 11
    still = SceneShift(probe_every=10, first_probe=True)
    assert all(still.update(f) == (0.0, 0.0) for f in _still_field_with_a_target(25))
    assert not still.moving
