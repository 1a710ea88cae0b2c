import numpy as np
import pytest

from spacetrack.enhance import DwtHsvEnhancer, enhance_dwt_hsv
from spacetrack.enhance.dwt_hsv import (
    adaptive_gamma,
    adjust_hue_saturation,
    circular_linear_correlation,
    percentiles,
    to_hsv,
    to_rgb,
)


def _background_v(rgb, mask):
    return rgb.max(axis=2)[mask].astype(np.float64)


@pytest.mark.parametrize("shape", [(1, 1, 3), (2, 3, 3), (7, 13, 3), (33, 47, 3), (121, 161, 3)])
@pytest.mark.parametrize("wavelet,level", [("haar", 2), ("db2", 3), ("sym4", 1)])
def test_shape_dtype_and_range_kept_for_any_size(shape, wavelet, level):
    rgb = np.random.default_rng(1).integers(0, 256, shape, dtype=np.uint8)
    out = enhance_dwt_hsv(rgb, wavelet=wavelet, level=level)
    assert out.shape == shape
    assert out.dtype == np.uint8
    assert out.flags.c_contiguous


def test_deterministic_and_input_untouched(dim_frame):
    before = dim_frame.rgb.copy()
    first = enhance_dwt_hsv(dim_frame.rgb)
    second = DwtHsvEnhancer()(dim_frame.rgb)
    assert first.tobytes() == second.tobytes()
    np.testing.assert_array_equal(dim_frame.rgb, before)


def test_dim_targets_gain_contrast_without_the_noise_floor_exploding(dim_frame, frame_contrast):
    out = enhance_dwt_hsv(dim_frame.rgb)
    before = frame_contrast(dim_frame.rgb, dim_frame.target, dim_frame.background)
    after = frame_contrast(out, dim_frame.target, dim_frame.background)
    assert after > 2.0 * before, (before, after)
    bg_in, bg_out = (
        _background_v(dim_frame.rgb, dim_frame.background),
        _background_v(out, dim_frame.background),
    )
    assert bg_out.mean() <= bg_in.mean(), "the sky must not be lifted"
    assert bg_out.std() < 3.0 * bg_in.std(), (bg_in.std(), bg_out.std())
    # and the targets are now plainly visible, not just relatively brighter
    assert out.max(axis=2)[dim_frame.target].mean() > 100


def test_denoising_is_what_holds_the_noise_floor(dim_frame):
    default = _background_v(enhance_dwt_hsv(dim_frame.rgb), dim_frame.background).std()
    raw = enhance_dwt_hsv(dim_frame.rgb, detail_threshold=0.0, bilateral_d=0)
    assert default < 0.5 * _background_v(raw, dim_frame.background).std()


def test_contrast_gain_holds_for_other_noise_draws(make_dim_frame, frame_contrast):
    for seed in (1, 2):
        frame = make_dim_frame(seed=seed)
        before = frame_contrast(frame.rgb, frame.target, frame.background)
        assert frame_contrast(enhance_dwt_hsv(frame.rgb), frame.target, frame.background) > 2.0 * before


def test_target_colour_is_kept(dim_frame):
    out = enhance_dwt_hsv(dim_frame.rgb)
    # the orange target centred at (150, 210) and the bluish one at (190, 60) keep their dominant channel
    orange = out[146:155, 206:215].reshape(-1, 3).mean(axis=0)
    blue = out[188:193, 58:63].reshape(-1, 3).mean(axis=0)
    assert orange[0] > orange[1] > orange[2]
    assert blue[2] > blue[0]


@pytest.mark.parametrize("value", [0, 200, 255])
def test_flat_frames_stay_flat_and_finite(value):
    rgb = np.full((16, 24, 3), value, np.uint8)
    out = enhance_dwt_hsv(rgb)
    assert np.ptp(out) == 0
    if value == 0:
        assert out.max() == 0


def test_adaptive_gamma_brightens_only_dark_bands():
    assert adaptive_gamma(0.3, target_mean=0.3, gamma_min=0.5) == 1.0
    assert adaptive_gamma(0.6, target_mean=0.3, gamma_min=0.5) == 1.0
    assert adaptive_gamma(0.0, target_mean=0.3, gamma_min=0.5) == 1.0
    assert adaptive_gamma(0.001, target_mean=0.3, gamma_min=0.5) == 0.5
    g = adaptive_gamma(0.2, target_mean=0.3, gamma_min=0.5)
    assert 0.5 < g < 1.0
    assert 0.2**g == pytest.approx(0.3)


def test_percentiles_match_numpy_to_the_bin_width():
    v = np.random.default_rng(0).random((97, 113), dtype=np.float32)
    got = percentiles(v, (1.0, 25.0, 99.9))
    np.testing.assert_allclose(got, np.percentile(v, [1.0, 25.0, 99.9]), atol=2 / 4096)


def test_circular_linear_correlation():
    rng = np.random.default_rng(0)
    v = rng.random(5000)
    hue = np.deg2rad(20 + 120 * v)  # hue follows brightness
    assert circular_linear_correlation(np.cos(hue), np.sin(hue), v) > 0.99
    noise = rng.uniform(0, 2 * np.pi, 5000)
    assert circular_linear_correlation(np.cos(noise), np.sin(noise), v) < 0.1


def _hsv_ramp(s_follows_v: bool):
    v = np.tile(np.linspace(0.05, 0.5, 64, dtype=np.float32), (32, 1))
    s = (v if s_follows_v else 0.55 - v).astype(np.float32)
    h = np.full_like(v, 30.0)
    return h, s, v


@pytest.mark.parametrize("s_follows_v", [True, False])
def test_saturation_follows_v_by_its_correlation(s_follows_v):
    h, s, v = _hsv_ramp(s_follows_v)
    brighter = np.minimum(v * 1.8, 1.0)
    _, s_new = adjust_hue_saturation(
        h, s, v, brighter, saturation_coupling=1.0, hue_smoothing=0.0, hue_sigma=1.5
    )
    _, s_kept = adjust_hue_saturation(
        h, s, v, brighter, saturation_coupling=0.0, hue_smoothing=0.0, hue_sigma=1.5
    )
    np.testing.assert_allclose(s_kept, s, atol=1e-6)
    if s_follows_v:
        assert (s_new >= s - 1e-6).all() and s_new.mean() > s.mean() + 0.05
    else:
        assert (s_new <= s + 1e-6).all() and s_new.mean() < s.mean() - 0.05


def test_hue_noise_is_smoothed_but_coherent_colour_kept():
    rng = np.random.default_rng(0)
    h = rng.uniform(0, 360, (64, 64)).astype(np.float32)
    h[20:40, 20:40] = 200.0  # a coherent blue patch in random-hue noise
    s = np.full((64, 64), 0.6, np.float32)
    v = rng.uniform(0.02, 0.1, (64, 64)).astype(np.float32)
    h_new, s_new = adjust_hue_saturation(
        h, s, v, v, saturation_coupling=1.0, hue_smoothing=1.0, hue_sigma=1.5
    )
    assert s_new[:10].mean() < 0.5 * s[:10].mean(), "random chroma must largely cancel"
    np.testing.assert_allclose(h_new[25:35, 25:35], 200.0, atol=0.5)
    assert s_new[25:35, 25:35].mean() == pytest.approx(0.6, abs=0.01)


def test_hsv_round_trip_is_lossless_on_uint8():
    rgb = np.random.default_rng(3).integers(0, 256, (40, 50, 3), dtype=np.uint8)
    np.testing.assert_array_equal(to_rgb(*to_hsv(rgb)), rgb)


@pytest.mark.parametrize(
    "bad,match",
    [
        (np.zeros((8, 8, 3), np.float32), "dtype float32"),
        (np.zeros((8, 8), np.uint8), r"shape \(8, 8\)"),
        (np.zeros((8, 8, 4), np.uint8), r"shape \(8, 8, 4\)"),
        (np.zeros((0, 8, 3), np.uint8), r"non-empty.*\(0, 8, 3\)"),
        ([[0, 0, 0]], "list"),
    ],
)
def test_bad_input_names_shape_or_dtype(bad, match):
    with pytest.raises(ValueError, match=match):
        enhance_dwt_hsv(bad)


@pytest.mark.parametrize(
    "params,match",
    [
        ({"wavelet": "nope"}, "wavelet='nope'"),
        ({"level": 0}, "level=0"),
        ({"target_mean": 1.5}, "target_mean=1.5"),
        ({"gamma_min": 0.0}, "gamma_min=0.0"),
        ({"detail_gain": -1.0}, "detail_gain=-1.0"),
        ({"bilateral_d": 2.5}, "bilateral_d=2.5"),
        ({"hue_sigma": 0.0}, "hue_sigma=0.0"),
        ({"hue_smoothing": 2.0}, "hue_smoothing=2.0"),
        ({"low_percentile": 60.0, "high_percentile": 50.0}, "low_percentile=60.0"),
    ],
)
def test_bad_parameters_are_named(params, match):
    with pytest.raises(ValueError, match=match):
        DwtHsvEnhancer(**params)


def test_unknown_parameter_is_rejected():
    with pytest.raises(TypeError, match="levels"):
        DwtHsvEnhancer(levels=2)


def test_non_contiguous_views_are_accepted(dim_frame):
    bgr_view = dim_frame.rgb[:, :, ::-1]
    np.testing.assert_array_equal(enhance_dwt_hsv(bgr_view), enhance_dwt_hsv(np.ascontiguousarray(bgr_view)))
