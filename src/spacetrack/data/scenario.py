"""Scenario parameters: what a sequence of each kind looks like (conf/data/scenario/*.yaml).

A scenario YAML lists only its differences from these defaults (the nominal scene); unknown keys are
an error. Speeds and star counts are given for a 640-pixel-wide image and scale with the width.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

from omegaconf import OmegaConf


@dataclass
class ScenarioParams:
    # moving targets
    num_targets: list[int] = field(default_factory=lambda: [2, 3])  # inclusive range per sequence
    class_weights: list[float] = field(default_factory=lambda: [1.0, 1.0, 1.0])  # satellite, rocket, debris
    depth_m: list[float] = field(default_factory=lambda: [45.0, 160.0])
    depth_rate_m: list[float] = field(default_factory=lambda: [-0.1, 0.1])  # metres per frame
    speed_px: list[float] = field(default_factory=lambda: [0.8, 3.0])  # image speed, px/frame at 640 px
    spin_deg: list[float] = field(default_factory=lambda: [0.3, 2.5])  # rotation, degrees per frame
    stop_prob: float = 0.2  # chance that a target slows to a full stop for a while
    stop_frames: list[int] = field(default_factory=lambda: [10, 25])
    ramp_prob: float = 0.3  # chance that a target's speed changes steadily over the sequence
    min_frames_in_view: int = 20
    # static objects and background
    num_static: list[int] = field(default_factory=lambda: [0, 0])  # parked satellites / rocket bodies
    planet_prob: float = 0.0  # chance of a planet limb in the field of view
    stars: int = 250  # per 640x480 field
    # light
    sun_phase_deg: list[float] = field(default_factory=lambda: [30.0, 110.0])  # sun-target-camera angle
    sun: float = 1.0  # irradiance: radiance of a white face square to the sun (1.0 = full scale)
    ambient: float = 0.0  # fill light on the night side; 0 keeps it as black as space
    exposure: list[float] = field(default_factory=lambda: [0.8, 1.1])  # sensor gain range
    exposure_jumps: int = 0  # sudden exposure changes per sequence
    exposure_jump_gain: list[float] = field(default_factory=lambda: [1.8, 3.0])
    exposure_jump_frames: list[int] = field(default_factory=lambda: [3, 12])
    glare: float = 0.0  # stray light from a source just outside the field (veiling glare)
    flare: float = 0.0  # lens-flare ghosts along the line through the image centre
    bloom: float = 0.0  # saturated light bleeding into neighbours
    # sensor and optics
    read_noise_dn: float = 1.2
    shot_noise: float = 0.5  # shot-noise std is shot_noise * sqrt(signal in DN)
    black_level_dn: float = 2.0
    hot_pixels: int = 0
    psf_sigma_px: float = 0.7
    motion_blur: float = 0.5  # open-shutter fraction of the frame time
    # special set-ups
    occlusion_pair: bool = False  # a near target passes in front of a far one, hiding it fully
    hidden_frames_min: int = 10
    slew_px: list[float] = field(default_factory=lambda: [0.0, 0.0])  # camera slew speed, px/frame at 640 px


SCENARIO_KEYS = {f.name for f in fields(ScenarioParams)}


def scenario_params(name: str, overrides) -> ScenarioParams:
    """Merge a scenario's YAML differences onto the defaults; unknown keys raise a clear error."""
    raw = OmegaConf.to_container(overrides, resolve=True) if overrides is not None else {}
    unknown = sorted(set(raw) - SCENARIO_KEYS)
    if unknown:
        raise ValueError(
            f"scenario {name!r}: unknown key(s) {unknown}; known keys are in "
            "spacetrack.data.scenario.ScenarioParams"
        )
    params = OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(ScenarioParams), raw))
    _check_ranges(name, params)
    return params


def _check_ranges(name: str, p: ScenarioParams) -> None:
    for f in fields(p):
        value = getattr(p, f.name)
        if isinstance(value, list) and f.name != "class_weights" and (len(value) != 2 or value[0] > value[1]):
            raise ValueError(f"scenario {name!r}: {f.name}={value} must be a [low, high] range")
    if p.num_targets[0] < 1 and not p.occlusion_pair:
        raise ValueError(f"scenario {name!r}: num_targets={p.num_targets} must allow at least one target")
    if len(p.class_weights) != 3 or min(p.class_weights) < 0 or sum(p.class_weights) <= 0:
        raise ValueError(f"scenario {name!r}: class_weights={p.class_weights} needs 3 non-negative weights")
