"""Re-exposure of a rendered frame: the same scene as the sensor would record it at another gain.

The renderer's sensor (`spacetrack.data.optics.sensor`) is linear: a pixel reads
`dn = gain * radiance * 255 + black_level` plus noise of variance `shot_noise**2 * dn + read_noise_dn**2`,
clipped to 0..255. Multiplying a frame's signal above the black level by `g` therefore gives the frame
an exposure `g` times as long would have given, up to its noise: dimmed, its own noise shrinks by `g`,
so noise of variance `g * (1 - g) * shot_noise**2 * signal + (1 - g**2) * read_noise_dn**2` is added to
restore the noise a dim exposure has; brightened, the signal clips at 255 as a saturated pixel does (no
noise is added: the frame's own noise is amplified with it). A detector trained with it sees every
target under the dim scenario's low exposure and the strong-light scenario's high one, not only the few
sequences rendered that way.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import albumentations as A
import numpy as np

from spacetrack.data.frame_store import FrameStore

# The gains drawn by default (`train.augment.exposure_gain`): the dim scenario's exposure is about a
# fifth of the nominal one, the strong-light scenario's with its jumps up to three times.
DEFAULT_GAIN = (0.15, 3.0)
# The noise a dimmed sample gets: the dim scenario's read and shot noise and the renderer's black level
# (`conf/data/scenario/dim.yaml`, `spacetrack.data.scenario.ScenarioParams`).
DIM_NOISE = {"read_noise_dn": 2.0, "shot_noise": 0.7, "black_level_dn": 2.0}


def exposure_probability(p: float) -> float:
    """`p` checked as the probability of re-exposing a sample (`train.augment.exposure`)."""
    if not 0 <= p <= 1:
        raise ValueError(f"train.augment.exposure is a probability in [0, 1], got {p}")
    return float(p)


def gain_range(gain: Sequence[float]) -> tuple[float, float]:
    """`gain` as a checked (low, high) range of positive gains."""
    if len(gain) != 2 or not 0 < float(gain[0]) <= float(gain[1]):
        raise ValueError(f"exposure gain must be a range [low, high] with 0 < low <= high, got {list(gain)}")
    return float(gain[0]), float(gain[1])


def log_uniform(u: float, low: float, high: float) -> float:
    """The gain at quantile `u` (a uniform draw in [0, 1)) of the log-uniform distribution on [low, high]."""
    a, b = math.log(low), math.log(high)
    return math.exp(a + (b - a) * u)


def reexpose(
    image: np.ndarray,
    gain: float,
    rng: np.random.Generator,
    *,
    read_noise_dn: float,
    shot_noise: float,
    black_level_dn: float,
) -> np.ndarray:
    """`image` (uint8, any shape) as an exposure `gain` times as long would have recorded it."""
    if gain <= 0:
        raise ValueError(f"exposure gain must be positive, got {gain}")
    signal = image.astype(np.float32) - np.float32(black_level_dn)  # below 0 where noise dipped under black
    dn = signal * np.float32(gain) + np.float32(black_level_dn)
    if gain < 1:
        shot = gain * (1 - gain) * shot_noise**2 * np.clip(signal, 0.0, None)
        var = shot + np.float32((1 - gain**2) * read_noise_dn**2)
        dn += np.sqrt(var, dtype=np.float32) * rng.standard_normal(dn.shape, dtype=np.float32)
    return np.clip(np.rint(dn), 0, 255).astype(np.uint8)


class Exposure(A.ImageOnlyTransform):
    """Re-expose the image by a gain drawn log-uniformly from `gain` ([low, high]), with `DIM_NOISE`;
    boxes are untouched."""

    def __init__(self, gain: Sequence[float] = DEFAULT_GAIN, p: float = 0.5) -> None:
        super().__init__(p=p)
        self.gain = gain_range(gain)

    def get_params(self) -> dict[str, Any]:
        gain = log_uniform(self.py_random.random(), *self.gain)
        return {"gain": gain, "noise_seed": self.py_random.getrandbits(63)}

    def apply(self, img: np.ndarray, gain: float = 1.0, noise_seed: int = 0, **params: Any) -> np.ndarray:
        return reexpose(img, gain, np.random.default_rng(noise_seed), **DIM_NOISE)

    def get_transform_init_args_names(self) -> tuple[str, ...]:
        return ("gain",)


class FrameExposure:
    """Re-exposure ahead of an input enhancement, for training an enhanced detector.

    The DWT/HSV enhancement adapts to each frame (its brightening follows the frame's mean, its stretch
    the frame's percentiles), so a dim exposure must be made before it, on the whole frame, as a dim
    frame would reach it: with probability `p` a sample's frame is read unenhanced from `raw`,
    re-exposed by a gain drawn log-uniformly from `gain` (with `DIM_NOISE`) and enhanced by `enhancer` (about 50 ms of CPU a
    640x480 frame); otherwise (None) the dataset reads its cached enhanced frame.
    """

    def __init__(
        self,
        raw: FrameStore,
        enhancer: Callable[[np.ndarray], np.ndarray],
        *,
        p: float,
        gain: Sequence[float],
    ) -> None:
        self.raw, self.enhancer = raw, enhancer
        self.p, self.gain = exposure_probability(p), gain_range(gain)

    def __call__(self, seq: str, index: int, rng: np.random.Generator) -> np.ndarray | None:
        if rng.random() >= self.p:
            return None
        gain = log_uniform(rng.random(), *self.gain)
        return self.enhancer(reexpose(np.asarray(self.raw.frame(seq, index)), gain, rng, **DIM_NOISE))
