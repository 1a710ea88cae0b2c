"""Planning a sequence: which objects, where they go, how they turn, the light and the camera.

A plan is pure data drawn from one seeded generator, so the same (config, seed) gives the same scene.
Trajectories are laid out in the image (a pixel path and a depth), then lifted to 3-D through the
camera, so that speeds, border crossings and occlusions can be placed exactly.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from spacetrack.data import geometry
from spacetrack.data.raster import Camera
from spacetrack.data.scenario import ScenarioParams

STATIC_ID_BASE = 1000  # ids of static objects in gt/static.txt start here


@dataclass
class ObjectPlan:
    """One object over the sequence. `progress[t]` is the distance travelled in units of the nominal step."""

    id: int
    class_id: int
    mesh: geometry.Mesh
    static: bool
    uv0: np.ndarray  # image position at frame 0 (pixels, no slew)
    uv_step: np.ndarray  # image displacement per unit of progress (pixels)
    depth0: float
    depth_step: float  # metres per unit of progress
    rot0: Rotation
    spin_axis: np.ndarray  # unit axis in the object frame
    spin_step: float  # radians per unit of progress
    progress: np.ndarray  # (T,) cumulative progress; constant for static objects

    def pose(self, t: int, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
        """(rotation 3x3, position in metres) at 0-based frame `t`."""
        s = self.progress[t]
        rot = self.rot0 * Rotation.from_rotvec(self.spin_axis * self.spin_step * s)
        depth = self.depth0 + self.depth_step * s
        return rot.as_matrix(), camera.unproject(self.uv0 + self.uv_step * s, depth)

    def centre(self, t: int) -> np.ndarray:
        return self.uv0 + self.uv_step * self.progress[t]

    def image_velocity(self, t: int) -> np.ndarray:
        """Pixels per frame around frame `t` (no slew)."""
        lo, hi = max(t - 1, 0), min(t + 1, len(self.progress) - 1)
        if hi == lo:
            return np.zeros(2)
        return self.uv_step * (self.progress[hi] - self.progress[lo]) / (hi - lo)

    def moving(self, t: int) -> bool:
        """Whether the object moves or turns at frame `t` (a stopped target is not in the motion mask)."""
        lo, hi = max(t - 1, 0), min(t + 1, len(self.progress) - 1)
        return bool(self.progress[hi] > self.progress[lo])


@dataclass
class ScenePlan:
    name: str
    scenario: str
    seed: list[int]
    camera: Camera
    num_frames: int
    params: ScenarioParams
    objects: list[ObjectPlan]
    sun_dir: np.ndarray
    exposure: np.ndarray  # (T,) sensor gain per frame
    slew: np.ndarray  # image displacement of the world per frame, pixels
    glare_uv: np.ndarray | None = None
    planet: dict | None = None
    hot_pixels: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=int))

    @property
    def moving(self) -> list[ObjectPlan]:
        return [o for o in self.objects if not o.static]

    @property
    def static(self) -> list[ObjectPlan]:
        return [o for o in self.objects if o.static]


def _uniform(rng: np.random.Generator, lo_hi) -> float:
    return float(rng.uniform(lo_hi[0], lo_hi[1]))


def _speed_profile(
    rng: np.random.Generator, p: ScenarioParams, num_frames: int, allow_stop: bool
) -> np.ndarray:
    """Cumulative progress (T,) for a speed multiplier that may ramp or stop for a while."""
    frames = np.arange(num_frames)
    speed = np.ones(num_frames)
    if rng.random() < p.ramp_prob:
        speed = np.linspace(rng.uniform(0.4, 1.6), rng.uniform(0.4, 1.6), num_frames)
    if allow_stop and num_frames >= 30 and rng.random() < p.stop_prob:
        ramp = 5
        hold = min(int(rng.integers(p.stop_frames[0], p.stop_frames[1] + 1)), num_frames // 3)
        start = int(rng.integers(ramp + 1, num_frames - hold - ramp - 1))
        speed = speed * np.interp(
            frames, [start - ramp, start, start + hold, start + hold + ramp], [1, 0, 0, 1]
        )
    return np.concatenate([[0.0], np.cumsum(speed[1:])])


def _pick_class(rng: np.random.Generator, p: ScenarioParams) -> int:
    w = np.asarray(p.class_weights, dtype=float)
    return int(rng.choice(len(w), p=w / w.sum()))


def _random_mover(
    rng: np.random.Generator, p: ScenarioParams, camera: Camera, num_frames: int, obj_id: int
) -> ObjectPlan:
    """A target that crosses the field somewhere in the sequence (it may enter or leave by a border)."""
    scale = camera.width / 640.0
    progress = _speed_profile(rng, p, num_frames, allow_stop=True)
    for _ in range(50):
        margin = 0.1 * np.array([camera.width, camera.height])
        mid = rng.uniform(margin, [camera.width, camera.height] - margin)
        angle = rng.uniform(0, 2 * np.pi)
        step = _uniform(rng, p.speed_px) * scale * np.array([np.cos(angle), np.sin(angle)])
        t_mid = int(
            rng.integers(int(0.2 * num_frames), max(int(0.8 * num_frames), int(0.2 * num_frames) + 1))
        )
        uv0 = mid - step * progress[t_mid]
        centres = uv0 + step * progress[:, None]
        inside = np.all((centres >= 0) & (centres < [camera.width, camera.height]), axis=1)
        if inside.sum() >= min(p.min_frames_in_view, num_frames // 2):
            break
    class_id = _pick_class(rng, p)
    return ObjectPlan(
        id=obj_id,
        class_id=class_id,
        mesh=geometry.build(geometry.CLASS_NAMES[class_id], rng),
        static=False,
        uv0=uv0,
        uv_step=step,
        depth0=_uniform(rng, p.depth_m),
        depth_step=_uniform(rng, p.depth_rate_m),
        rot0=Rotation.random(random_state=rng),
        spin_axis=Rotation.random(random_state=rng).apply([0.0, 0.0, 1.0]),
        spin_step=np.radians(_uniform(rng, p.spin_deg)),
        progress=progress,
    )


def _static_object(rng: np.random.Generator, camera: Camera, num_frames: int, obj_id: int) -> ObjectPlan:
    """A parked satellite or rocket body: visible, detectable, never moving."""
    class_id = int(rng.choice([0, 1], p=[0.7, 0.3]))
    margin = 0.15 * np.array([camera.width, camera.height])
    return ObjectPlan(
        id=obj_id,
        class_id=class_id,
        mesh=geometry.build(geometry.CLASS_NAMES[class_id], rng),
        static=True,
        uv0=rng.uniform(margin, [camera.width, camera.height] - margin),
        uv_step=np.zeros(2),
        depth0=float(rng.uniform(70.0, 160.0)),
        depth_step=0.0,
        rot0=Rotation.random(random_state=rng),
        spin_axis=np.array([0.0, 0.0, 1.0]),
        spin_step=0.0,
        progress=np.zeros(num_frames),
    )


def occlusion_pair(
    rng: np.random.Generator, p: ScenarioParams, camera: Camera, num_frames: int, first_id: int
) -> tuple[ObjectPlan, ObjectPlan]:
    """A near rocket body (broadside, spinning about its axis) passing in front of a small far target.

    They move in opposite directions along the same image row and meet near mid-sequence, so the far
    one disappears behind the near one and re-appears on the other side.
    """
    scale = camera.width / 640.0
    sign = rng.choice([-1.0, 1.0])
    near_depth = float(rng.uniform(45.0, 60.0))
    far_depth = float(rng.uniform(150.0, 210.0))
    near_speed = float(rng.uniform(2.5, 3.5)) * scale
    far_speed = float(rng.uniform(1.5, 2.5)) * scale
    t_meet = float(rng.uniform(0.42, 0.58) * num_frames)
    meet = np.array([rng.uniform(0.35, 0.65) * camera.width, rng.uniform(0.3, 0.7) * camera.height])
    tilt = Rotation.from_rotvec([0.0, 0.0, rng.uniform(-0.08, 0.08)])
    frames = np.arange(num_frames, dtype=float)
    near_step = np.array([sign * near_speed, 0.0])
    far_step = np.array([-sign * far_speed, rng.uniform(-0.05, 0.05) * scale])
    near = ObjectPlan(
        id=first_id,
        class_id=1,
        mesh=geometry.rocket_body(rng, radius=rng.uniform(1.5, 1.9), length=rng.uniform(8.0, 11.0)),
        static=False,
        uv0=meet - near_step * t_meet,
        uv_step=near_step,
        depth0=near_depth,
        depth_step=0.0,
        rot0=tilt,
        spin_axis=np.array([1.0, 0.0, 0.0]),
        spin_step=np.radians(rng.uniform(1.0, 3.0)),
        progress=frames,
    )
    far = ObjectPlan(
        id=first_id + 1,
        class_id=2,
        mesh=geometry.debris(rng),
        static=False,
        uv0=meet + rng.uniform(-2, 2, size=2) * scale - far_step * t_meet,
        uv_step=far_step,
        depth0=far_depth,
        depth_step=0.0,
        rot0=Rotation.random(random_state=rng),
        spin_axis=Rotation.random(random_state=rng).apply([0.0, 0.0, 1.0]),
        spin_step=np.radians(rng.uniform(0.5, 2.0)),
        progress=frames.copy(),
    )
    return near, far


def _sun_direction(rng: np.random.Generator, phase_deg) -> np.ndarray:
    """Unit vector towards the sun at a phase angle from the direction back to the camera (-z)."""
    phase = np.radians(_uniform(rng, phase_deg))
    psi = rng.uniform(0, 2 * np.pi)
    return np.array([np.sin(phase) * np.cos(psi), np.sin(phase) * np.sin(psi), -np.cos(phase)])


def _exposure(rng: np.random.Generator, p: ScenarioParams, num_frames: int) -> np.ndarray:
    gain = np.full(num_frames, _uniform(rng, p.exposure))
    for _ in range(p.exposure_jumps):
        start = int(rng.integers(1, max(num_frames - 2, 2)))
        length = int(rng.integers(p.exposure_jump_frames[0], p.exposure_jump_frames[1] + 1))
        gain[start : start + length] *= _uniform(rng, p.exposure_jump_gain)
    return gain


def _glare_position(rng: np.random.Generator, camera: Camera) -> np.ndarray:
    """A point just outside (or on) a random border of the field."""
    w, h = camera.width, camera.height
    side = int(rng.integers(4))
    out = rng.uniform(0.0, 0.25) * max(w, h)
    along = rng.uniform(0.1, 0.9)
    return np.array(
        [[along * w, -out], [w + out, along * h], [along * w, h + out], [-out, along * h]][side], dtype=float
    )


def _planet(rng: np.random.Generator, camera: Camera) -> dict:
    """A planet limb: a big disc whose edge cuts across a part of the field."""
    w, h = camera.width, camera.height
    radius = rng.uniform(1.5, 3.0) * w
    psi = rng.uniform(0, 2 * np.pi)
    inside = rng.uniform(0.15, 0.35) * h  # how deep the disc reaches into the field
    centre = np.array([w / 2, h / 2]) + (radius + min(w, h) / 2 - inside) * np.array(
        [np.cos(psi), np.sin(psi)]
    )
    return {"centre": centre, "radius": float(radius), "cloud_seed": int(rng.integers(2**31))}


def plan_sequence(
    *, name: str, scenario: str, params: ScenarioParams, camera: Camera, num_frames: int, seed: list[int]
) -> ScenePlan:
    """Draw a whole sequence from `seed` (e.g. [dataset seed, sequence index])."""
    rng = np.random.default_rng(seed)
    objects: list[ObjectPlan] = []
    if params.occlusion_pair:
        objects.extend(occlusion_pair(rng, params, camera, num_frames, first_id=1))
    for _ in range(int(rng.integers(params.num_targets[0], params.num_targets[1] + 1))):
        objects.append(_random_mover(rng, params, camera, num_frames, obj_id=len(objects) + 1))
    for k in range(int(rng.integers(params.num_static[0], params.num_static[1] + 1))):
        objects.append(_static_object(rng, camera, num_frames, obj_id=STATIC_ID_BASE + k))
    slew_speed = _uniform(rng, params.slew_px) * camera.width / 640.0
    slew_angle = rng.uniform(0, 2 * np.pi)
    n_hot = params.hot_pixels
    return ScenePlan(
        name=name,
        scenario=scenario,
        seed=list(seed),
        camera=camera,
        num_frames=num_frames,
        params=params,
        objects=objects,
        sun_dir=_sun_direction(rng, params.sun_phase_deg),
        exposure=_exposure(rng, params, num_frames),
        slew=slew_speed * np.array([np.cos(slew_angle), np.sin(slew_angle)]),
        glare_uv=_glare_position(rng, camera) if params.glare > 0 or params.flare > 0 else None,
        planet=_planet(rng, camera) if rng.random() < params.planet_prob else None,
        hot_pixels=np.stack([rng.integers(0, camera.width, n_hot), rng.integers(0, camera.height, n_hot)], 1),
    )
