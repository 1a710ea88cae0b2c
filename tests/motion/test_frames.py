import numpy as np
import pytest

from spacetrack.motion import (
    KNN,
    MOG2,
    FiveFrameDifference,
    Fusion,
    ThreeFrameDifference,
    TwoFrameDifference,
    ViBe,
)
from spacetrack.motion.frames import to_grey

FACTORIES = {
    "two": TwoFrameDifference,
    "three": ThreeFrameDifference,
    "five": FiveFrameDifference,
    "vibe": ViBe,
    "mog2": MOG2,
    "knn": KNN,
    "fusion": lambda: Fusion(difference=FiveFrameDifference(), background=ViBe()),
}


def _feed(detector, n: int, shape=(32, 48, 3)) -> None:
    for _ in range(n):
        detector.apply(np.zeros(shape, np.uint8))


@pytest.mark.parametrize("name", FACTORIES)
@pytest.mark.parametrize(
    ("bad", "match"),
    [
        (np.zeros((32, 40, 3), np.uint8), "frame 3: shape"),
        (np.zeros((32, 48), np.uint8), "frame 3: shape"),
        (np.zeros((0, 48, 3), np.uint8), "frame 3: empty"),
        (np.zeros((32, 48, 3), np.float32), "frame 3: dtype float32"),
        (np.full((32, 48, 3), np.nan), "frame 3: contains NaN"),
        (np.zeros((32, 48, 4), np.uint8), "frame 3: shape"),
        ([[0, 1]], "frame 3: expected a numpy array"),
    ],
)
def test_bad_frame_names_its_index(name, bad, match):
    detector = FACTORIES[name]()
    _feed(detector, 3)
    with pytest.raises(ValueError, match=match):
        detector.apply(bad)


@pytest.mark.parametrize("name", FACTORIES)
def test_reset_restores_initial_state(name, scene, run):
    detector = FACTORIES[name]()
    frames, _ = scene(10, seed=3)
    first = run(detector, frames)
    detector.reset()
    # a frame of another size is fine after a reset: it is a new sequence
    _feed(detector, 2, shape=(16, 16))
    detector.reset()
    second = run(detector, frames)
    assert sorted(first) == sorted(second)
    assert all(np.array_equal(first[t], second[t]) for t in first)


# OpenCV's subtractors model colour unless told to work on grey, as every other detector does.
ON_GREY = FACTORIES | {"mog2": lambda: MOG2(grey=True), "knn": lambda: KNN(grey=True)}


@pytest.mark.parametrize("name", ON_GREY)
def test_grey_and_rgb_frames_of_one_scene_give_the_same_masks(name, scene, run):
    frames, _ = scene(10, seed=3)
    grey = [to_grey(frame) for frame in frames]
    by_rgb = run(ON_GREY[name](), [np.dstack([g] * 3) for g in grey])
    by_grey = run(ON_GREY[name](), grey)
    by_one_channel = run(ON_GREY[name](), [g[..., None] for g in grey])
    assert by_rgb and sorted(by_rgb) == sorted(by_grey) == sorted(by_one_channel)
    for t, mask in by_rgb.items():
        assert np.array_equal(mask, by_grey[t]) and np.array_equal(mask, by_one_channel[t]), t
