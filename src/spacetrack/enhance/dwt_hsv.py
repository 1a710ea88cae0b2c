"""The paper's DWT/HSV input enhancement (Fig. 10) for dark space frames.

Pipeline, each step a function so that the benchmark can time it:

1. `to_hsv`: RGB uint8 -> H in degrees [0, 360), S and V in [0, 1], float32.
2. `wavelet_brighten`: 2-D DWT of V (PyWavelets, `wavelet`, `level`). The low band, normalised to [0, 1],
   goes through a gamma curve adaptive to its mean, `gamma = clip(log(target_mean) / log(mean), gamma_min,
   1)`: a dark frame is brightened, a frame already as bright as `target_mean` is left alone, and
   `gamma_min` bounds the slope at the noise floor. Every detail band is soft-thresholded at
   `detail_threshold * sigma`, where sigma is the noise level estimated from the finest diagonal band
   (median absolute value / 0.6745), then multiplied by `detail_gain` (> 1 sharpens). Inverse DWT; the
   reconstruction is cropped back to the input size, so odd sizes work.
3. `bilateral`: OpenCV bilateral filter on V (`bilateral_d` pixels wide, `bilateral_sigma_color` in V
   units, `bilateral_sigma_space` in pixels) to smooth the remaining noise without blurring edges.
4. `adjust_hue_saturation`, adaptive to how H and S correlate with the input V:
   - hue: R in [0, 1] is the circular-linear correlation between H and V (Mardia). The chroma vector
     S * (cos H, sin H) is blended with its Gaussian-blurred copy (`hue_sigma` pixels) with weight
     `w = hue_smoothing * (1 - R)`, and H and S are read back from the blend. When hue does not follow
     brightness (R ~ 0, the sensor noise of a dark frame) hue is mostly noise, and the blend replaces it
     by its local saturation-weighted mean, so random colour speckle cancels to grey while coherent target
     colours stay; when hue follows brightness (R ~ 1) it carries signal and is kept.
   - saturation: r in [-1, 1] is the Pearson correlation between S and the input V. S is multiplied by
     `(V_out / V_in) ** (saturation_coupling * r)`: where colour and brightness go together (r > 0),
     S grows with the brightening; where bright means white (r < 0), brightened pixels lose saturation
     instead of turning into vivid noise; r = 0 keeps S, i.e. the RGB ratios.
5. `stretch`: linear histogram stretch of V between its `low_percentile` and `high_percentile` (read
   from a 4096-bin histogram of V), clipped to [0, 1].
6. `to_rgb`: back to RGB uint8 (rounded).

All parameters are keyword arguments of `DwtHsvEnhancer` and keys of `conf/enhance/dwt_hsv.yaml`.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any, ClassVar

import cv2
import numpy as np
import pywt

from spacetrack.enhance.base import check_rgb

# Keeps V ratios finite on black pixels: one grey level.
_EPS = np.float32(1 / 255)
# Global statistics (noise level, correlations) are taken on every fourth row and column: 16x cheaper,
# and a 640x480 frame still gives 19,200 samples.
_SUB = (slice(None, None, 4), slice(None, None, 4))
# Percentiles are read from a histogram of this many bins over [0, 1] (resolution 1/4096).
_BINS = 4096


def to_hsv(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """RGB uint8 (H, W, 3) -> (hue in degrees [0, 360), saturation [0, 1], value [0, 1]), float32 each."""
    # Hue and saturation do not depend on the scale of RGB: only V needs dividing by 255.
    h, s, v = cv2.split(cv2.cvtColor(rgb.astype(np.float32), cv2.COLOR_RGB2HSV))
    v *= np.float32(1 / 255)
    return h, s, v


def to_rgb(h: np.ndarray, s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Hue in degrees, saturation and value in [0, 1] (float32) -> RGB uint8 (H, W, 3), rounded."""
    rgb = cv2.cvtColor(cv2.merge([h, s, v]), cv2.COLOR_HSV2RGB)
    return cv2.convertScaleAbs(rgb, alpha=255.0)


def adaptive_gamma(mean: float, *, target_mean: float, gamma_min: float) -> float:
    """The exponent that maps a band of this mean (in [0, 1]) to `target_mean`, limited to [gamma_min, 1]."""
    if not 0 < mean < target_mean:
        return 1.0
    return min(1.0, max(gamma_min, math.log(target_mean) / math.log(mean)))


def wavelet_brighten(
    v: np.ndarray,
    *,
    wavelet: str,
    level: int,
    target_mean: float,
    gamma_min: float,
    detail_gain: float,
    detail_threshold: float,
) -> np.ndarray:
    """V in [0, 1] (float32, any size) -> V with brightened low band and denoised, gained detail bands."""
    rows, cols = v.shape
    # A level deeper than the image allows would only filter padding; an image shorter than the filter
    # still gets one level (pywt warns about its boundary effects, which are expected there).
    max_level = pywt.dwt_max_level(min(rows, cols), wavelet)
    level = max(1, min(level, max_level))
    with warnings.catch_warnings():
        if max_level == 0:
            warnings.simplefilter("ignore", UserWarning)
        coeffs = pywt.wavedec2(v, wavelet, level=level, mode="symmetric")
    # Each level multiplies the low band by the sum of the low-pass filter, once per axis.
    scale = float(np.sum(pywt.Wavelet(wavelet).dec_lo)) ** (2 * level)
    low = np.clip(coeffs[0] * np.float32(1 / scale), 0.0, 1.0)
    gamma = adaptive_gamma(float(low.mean()), target_mean=target_mean, gamma_min=gamma_min)
    if gamma != 1.0:
        low = np.power(low, np.float32(gamma))
    coeffs[0] = low * np.float32(scale)
    finest_diagonal = coeffs[-1][2]
    sigma = float(np.median(np.abs(finest_diagonal[_SUB]))) / 0.6745
    threshold = detail_threshold * sigma
    coeffs[1:] = [tuple(soft_threshold(d, threshold, detail_gain) for d in bands) for bands in coeffs[1:]]
    out = pywt.waverec2(coeffs, wavelet, mode="symmetric")[:rows, :cols]
    return np.clip(out, 0.0, 1.0).astype(np.float32, copy=False)


def soft_threshold(d: np.ndarray, threshold: float, gain: float) -> np.ndarray:
    """`gain * sign(d) * max(|d| - threshold, 0)`, written as d - clip(d, -t, t): two passes and no
    division (pywt.threshold divides by |d|, which is slower and gives NaN at d = 0 with t = 0)."""
    out = np.clip(d, -threshold, threshold)
    np.subtract(d, out, out=out)
    out *= np.float32(gain)
    return out


def bilateral(
    v: np.ndarray, *, bilateral_d: int, bilateral_sigma_color: float, bilateral_sigma_space: float
) -> np.ndarray:
    """Edge-preserving smoothing of V (float32 in [0, 1]); `bilateral_d=0` switches it off."""
    if bilateral_d == 0:
        return v
    return cv2.bilateralFilter(v, bilateral_d, bilateral_sigma_color, bilateral_sigma_space)


def pearson(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of two equally shaped arrays; 0 where either is constant."""
    # Element-wise sums rather than a BLAS dot: no thread start-up for a 77k-sample vector.
    a = a.astype(np.float64) - a.mean(dtype=np.float64)
    b = b.astype(np.float64) - b.mean(dtype=np.float64)
    den = math.sqrt(float(np.sum(a * a)) * float(np.sum(b * b)))
    return float(np.sum(a * b)) / den if den > 0 else 0.0


def circular_linear_correlation(cos_h: np.ndarray, sin_h: np.ndarray, v: np.ndarray) -> float:
    """Mardia's circular-linear correlation in [0, 1] between an angle (given by cos, sin) and a value."""
    r_vc, r_vs, r_cs = pearson(v, cos_h), pearson(v, sin_h), pearson(cos_h, sin_h)
    if 1 - r_cs * r_cs <= 1e-12:
        return 0.0
    r2 = (r_vc * r_vc + r_vs * r_vs - 2 * r_vc * r_vs * r_cs) / (1 - r_cs * r_cs)
    return math.sqrt(min(1.0, max(0.0, r2)))


def adjust_hue_saturation(
    h: np.ndarray,
    s: np.ndarray,
    v_in: np.ndarray,
    v_out: np.ndarray,
    *,
    saturation_coupling: float,
    hue_smoothing: float,
    hue_sigma: float,
) -> tuple[np.ndarray, np.ndarray]:
    """New (hue in degrees, saturation in [0, 1]) from their correlation with V; see the module docstring."""
    radians = np.deg2rad(h[_SUB])
    r_hv = circular_linear_correlation(np.cos(radians), np.sin(radians), v_in[_SUB])
    r_sv = pearson(s[_SUB], v_in[_SUB])
    weight = hue_smoothing * (1.0 - r_hv)
    if weight > 0:
        cx, cy = cv2.polarToCart(s, h, angleInDegrees=True)  # the chroma vector S * (cos H, sin H)
        cx = cv2.addWeighted(cx, 1.0 - weight, cv2.GaussianBlur(cx, (0, 0), hue_sigma), weight, 0.0)
        cy = cv2.addWeighted(cy, 1.0 - weight, cv2.GaussianBlur(cy, (0, 0), hue_sigma), weight, 0.0)
        s, h = cv2.cartToPolar(cx, cy, angleInDegrees=True)
    exponent = saturation_coupling * r_sv
    if exponent != 0:
        s = cv2.multiply(s, cv2.pow(cv2.divide(v_out + _EPS, v_in + _EPS), exponent))
    return h, np.clip(s, 0.0, 1.0)


def percentiles(v: np.ndarray, q: tuple[float, ...]) -> list[float]:
    """Percentiles `q` (0-100) of V in [0, 1] from its histogram: each is the upper edge of the first bin
    whose cumulative count reaches q% of the pixels (exact to 1/4096, and far cheaper than sorting)."""
    hist = cv2.calcHist([v], [0], None, [_BINS], [0.0, 1.0 + 1e-6]).ravel()
    cum = np.cumsum(hist, dtype=np.float64)
    idx = np.searchsorted(cum, np.asarray(q, dtype=np.float64) * (cum[-1] / 100.0))
    return [min(1.0, (int(i) + 1) / _BINS) for i in idx]


def stretch(v: np.ndarray, *, low_percentile: float, high_percentile: float) -> np.ndarray:
    """V linearly mapped so that its low/high percentiles become 0/1, clipped; a flat V is returned as is."""
    lo, hi = percentiles(v, (low_percentile, high_percentile))
    if hi - lo <= 1e-6:
        return v
    return np.clip((v - np.float32(lo)) * np.float32(1.0 / (hi - lo)), 0.0, 1.0)


@dataclass(frozen=True, kw_only=True)
class DwtHsvEnhancer:
    """The DWT/HSV enhancement with its parameters (keyword arguments = keys of conf/enhance/dwt_hsv.yaml).

    Calling it on an RGB uint8 (H, W, 3) frame returns a new RGB uint8 frame of the same shape;
    the same input gives the same bytes. Out-of-range parameters raise ValueError at construction.
    """

    name: ClassVar[str] = "dwt_hsv"

    wavelet: str = "db2"
    level: int = 2
    target_mean: float = 0.3
    gamma_min: float = 0.5
    detail_gain: float = 1.5
    detail_threshold: float = 3.0
    bilateral_d: int = 5
    bilateral_sigma_color: float = 0.1
    bilateral_sigma_space: float = 3.0
    saturation_coupling: float = 1.0
    hue_smoothing: float = 1.0
    hue_sigma: float = 1.5
    low_percentile: float = 25.0
    high_percentile: float = 99.9

    def __post_init__(self) -> None:
        if self.wavelet not in pywt.wavelist(kind="discrete"):
            raise ValueError(
                f"wavelet={self.wavelet!r} is not a discrete PyWavelets wavelet (e.g. haar, db2)"
            )
        if not (isinstance(self.level, int) and self.level >= 1):
            raise ValueError(f"level={self.level!r} must be an integer >= 1")
        if not 0 < self.target_mean < 1:
            raise ValueError(f"target_mean={self.target_mean} must lie in (0, 1)")
        if not 0 < self.gamma_min <= 1:
            raise ValueError(f"gamma_min={self.gamma_min} must lie in (0, 1]")
        for key in ("detail_gain", "detail_threshold", "saturation_coupling"):
            if getattr(self, key) < 0:
                raise ValueError(f"{key}={getattr(self, key)} must be >= 0")
        if not (isinstance(self.bilateral_d, int) and self.bilateral_d >= 0):
            raise ValueError(f"bilateral_d={self.bilateral_d!r} must be an integer >= 0 (0 switches it off)")
        for key in ("bilateral_sigma_color", "bilateral_sigma_space", "hue_sigma"):
            if getattr(self, key) <= 0:
                raise ValueError(f"{key}={getattr(self, key)} must be > 0")
        if not 0 <= self.hue_smoothing <= 1:
            raise ValueError(f"hue_smoothing={self.hue_smoothing} must lie in [0, 1]")
        if not 0 <= self.low_percentile < self.high_percentile <= 100:
            raise ValueError(
                f"percentiles low_percentile={self.low_percentile}, high_percentile={self.high_percentile} "
                "must satisfy 0 <= low < high <= 100"
            )

    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        h, s, v = to_hsv(check_rgb(rgb))
        v_dwt = wavelet_brighten(
            v,
            wavelet=self.wavelet,
            level=self.level,
            target_mean=self.target_mean,
            gamma_min=self.gamma_min,
            detail_gain=self.detail_gain,
            detail_threshold=self.detail_threshold,
        )
        v_bil = bilateral(
            v_dwt,
            bilateral_d=self.bilateral_d,
            bilateral_sigma_color=self.bilateral_sigma_color,
            bilateral_sigma_space=self.bilateral_sigma_space,
        )
        h, s = adjust_hue_saturation(
            h,
            s,
            v,
            v_bil,
            saturation_coupling=self.saturation_coupling,
            hue_smoothing=self.hue_smoothing,
            hue_sigma=self.hue_sigma,
        )
        v_out = stretch(v_bil, low_percentile=self.low_percentile, high_percentile=self.high_percentile)
        return to_rgb(h, s, v_out)


def enhance_dwt_hsv(rgb: np.ndarray, **params: Any) -> np.ndarray:
    """Enhance one RGB uint8 (H, W, 3) frame; `params` are `DwtHsvEnhancer`'s keyword arguments."""
    return DwtHsvEnhancer(**params)(rgb)
