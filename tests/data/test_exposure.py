import numpy as np
import pytest

from spacetrack.data.exposure import Exposure, FrameExposure, reexpose
from spacetrack.data.frame_store import FrameStore
from spacetrack.data.yolo_dataset import apply_augmentation, build_augmentation

NOISE = {"read_noise_dn": 2.0, "shot_noise": 0.7, "black_level_dn": 2.0}
STILL = {"hue": 0, "saturation": 0, "value": 0, "fliplr": 0.0, "flipud": 0.0, "scale": 0.0, "translate": 0.0}


def test_dimming_scales_the_signal_and_adds_the_noise_a_short_exposure_has():
    flat = np.full((400, 400), 202, dtype=np.uint8)  # 200 DN of signal over the black level, noiseless
    gain = 0.25
    out = reexpose(flat, gain, np.random.default_rng(0), **NOISE).astype(np.float64)
    assert out.mean() == pytest.approx(2.0 + 200 * gain, abs=0.1)
    # var = g (1 - g) shot^2 signal + (1 - g^2) read^2 = 0.1875 * 0.49 * 200 + 0.9375 * 4
    assert out.std() == pytest.approx(np.sqrt(0.1875 * 0.49 * 200 + 0.9375 * 4), rel=0.03)


def test_brightening_clips_like_a_saturated_pixel_and_adds_no_noise():
    image = np.array([[2, 50, 130, 250]], dtype=np.uint8)
    out = reexpose(image, 2.0, np.random.default_rng(0), **NOISE)
    assert out.tolist() == [[2, 98, 255, 255]]


def test_gain_one_leaves_the_frame_as_it_is():
    image = np.random.default_rng(1).integers(0, 256, (32, 32, 3), dtype=np.uint8)
    assert np.array_equal(reexpose(image, 1.0, np.random.default_rng(0), **NOISE), image)


def test_augmentation_reexposes_reproducibly_and_keeps_the_boxes():
    augment = build_augmentation(**STILL, exposure=1.0, exposure_gain=[0.2, 0.2])
    image = np.full((64, 64, 3), 102, dtype=np.uint8)
    labels = np.array([[1, 0.5, 0.5, 0.25, 0.25]], dtype=np.float32)
    out, out_labels = apply_augmentation(augment, image, labels, (0, 0, 3))
    again, _ = apply_augmentation(augment, image, labels, (0, 0, 3))
    assert np.array_equal(out, again)
    assert out.astype(float).mean() == pytest.approx(2 + 100 * 0.2, abs=0.5)
    np.testing.assert_allclose(out_labels, labels, atol=1e-6)
    other, _ = apply_augmentation(augment, image, labels, (0, 0, 4))
    assert not np.array_equal(out, other)  # the noise is drawn per sample


def test_gains_are_drawn_over_the_whole_range():
    transform = Exposure(gain=(0.15, 3.0), p=1.0)
    transform.set_random_seed(0)
    gains = np.array([transform.get_params()["gain"] for _ in range(2000)])
    assert gains.min() >= 0.15 and gains.max() <= 3.0
    assert (gains < 0.4).mean() == pytest.approx(np.log(0.4 / 0.15) / np.log(20), abs=0.04)  # log-uniform


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"exposure": 1.5}, "train.augment.exposure is a probability in \\[0, 1\\], got 1.5"),
        ({"exposure": 0.5, "exposure_gain": [2.0, 0.5]}, "got \\[2.0, 0.5\\]"),
        ({"exposure": 0.5, "exposure_gain": [0.0, 1.0]}, "0 < low <= high"),
        ({"exposure": 0.5, "exposure_gain": [0.5]}, "a range \\[low, high\\]"),
    ],
)
def test_bad_exposure_settings_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        build_augmentation(**STILL, **kwargs)


def test_frame_exposure_reexposes_the_raw_frame_then_enhances_it(tiny_dataset, tmp_path):
    raw = FrameStore(root=tiny_dataset, cache_dir=tmp_path / "frames", progress=False)
    seq = "seq_000_nominal"
    frame = np.asarray(raw.frame(seq, 1))
    invert = lambda image: 255 - image  # noqa: E731 - any enhancer
    never = FrameExposure(raw, invert, p=0.0, gain=[0.5, 0.5])
    assert all(never(seq, 1, np.random.default_rng(i)) is None for i in range(20))
    always = FrameExposure(raw, invert, p=1.0, gain=[0.5, 0.5])
    out = always(seq, 1, np.random.default_rng(7))
    rng = np.random.default_rng(7)
    rng.random(), rng.random()  # the draws of p and of the gain
    assert np.array_equal(out, 255 - reexpose(frame, 0.5, rng, **NOISE))
    with pytest.raises(ValueError, match="got 2"):
        FrameExposure(raw, invert, p=2, gain=[0.5, 0.5])
