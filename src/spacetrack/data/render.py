"""Rendering a planned sequence frame by frame, with its exact ground truth.

The truth comes from the same silhouettes that make the image: objects are composited far to near, an
owner map records which object each pixel shows, and boxes, visibility and motion masks are read from
it. Image-only effects (motion blur, optics, noise, stray light) never change the truth.

Two truths are offered (`TRUTH_MODES`, the dataset's `truth` key):
- "silhouette" (`SequenceRenderer`'s default, the geometric truth): every pixel of an object's
  silhouette counts, lit or not, so a target half in its own shadow keeps the box of its whole outline.
- "seen" (the datasets' default, `conf/data/default.yaml`): only the pixels the camera can show count:
  an object pixel counts where it differs from what lies behind it (the sky without its stars, or a
  farther object), in some colour channel and exposed by the frame's gain, by at least `seen_snr` times
  the sensor noise there (sky, stray light, black level), once the optics' blur (the point-spread
  function, `psf_sigma_px`) has spread it as the image spreads it: a lone faint pixel or a one-pixel rim
  just above the noise before the blur is below it in the image, and does not stretch the box over the
  dark body between it and the lit part (a rocket body lit only at its end keeps the box of that end).
  A face turned from the sun (black, as `ambient` 0 leaves it) is not seen against black space but is
  seen against a lit planet or a lit target behind it; a target with no seen pixel is hidden in that
  frame like an occluded one. This is the box a person marking what the image shows would draw.
Both come from the same plan and image: only the labels differ.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from spacetrack.data import optics
from spacetrack.data.raster import Layer, render_mesh
from spacetrack.data.scene import ObjectPlan, ScenePlan

TRUTH_MODES = ("silhouette", "seen")


def check_truth(truth: str, seen_snr: float, prefix: str = "") -> None:
    """Refuse a truth mode or seen_snr the renderer cannot use; `prefix` names their config section."""
    if truth not in TRUTH_MODES:
        raise ValueError(f"{prefix}truth={truth!r}: expected one of {', '.join(TRUTH_MODES)}")
    if not seen_snr > 0:
        raise ValueError(f"{prefix}seen_snr={seen_snr}: expected a positive signal-to-noise ratio")


@dataclass(frozen=True)
class TruthRow:
    """One object in one frame. Box (x, y, w, h) in pixels, 0-based, covering columns x..x+w-1."""

    id: int
    class_id: int
    static: bool
    x: int
    y: int
    w: int
    h: int
    visibility: float  # visible pixels / whole silhouette (unclipped, unoccluded)
    visible_px: int
    occluded_px: int  # in-frame silhouette pixels hidden by nearer objects


@dataclass
class FrameTruth:
    rows: list[TruthRow]
    motion_mask: np.ndarray  # (H, W) bool: visible pixels of targets moving in this frame


def _clip(layer: Layer, width: int, height: int) -> tuple[tuple[slice, slice], tuple[slice, slice]] | None:
    """(image slices, layer slices) of the part of `layer` inside the frame, or None."""
    h, w = layer.mask.shape
    xa, ya = max(layer.x0, 0), max(layer.y0, 0)
    xb, yb = min(layer.x0 + w, width), min(layer.y0 + h, height)
    if xa >= xb or ya >= yb:
        return None
    return (
        (slice(ya, yb), slice(xa, xb)),
        (slice(ya - layer.y0, yb - layer.y0), slice(xa - layer.x0, xb - layer.x0)),
    )


def _tight_box(pixels: np.ndarray, x_off: int, y_off: int) -> tuple[int, int, int, int]:
    rows = np.flatnonzero(pixels.any(axis=1))
    cols = np.flatnonzero(pixels.any(axis=0))
    return (
        x_off + int(cols[0]),
        y_off + int(rows[0]),
        int(cols[-1] - cols[0] + 1),
        int(rows[-1] - rows[0] + 1),
    )


def frame_truth(
    objects: list[ObjectPlan],
    layers: list[Layer | None],
    t: int,
    width: int,
    height: int,
    seen: tuple[np.ndarray, np.ndarray] | None = None,
) -> FrameTruth:
    """Boxes, visibility and the motion mask of frame `t` from the objects' layers.

    seen: None (every silhouette pixel counts), or (sky, min_contrast, psf_sigma): the radiance
    (height, width, 3) behind every object, the (height, width) contrast an object pixel needs and the
    optics' blur (Gaussian sigma, pixels): it counts only where the largest channel difference between
    the object's radiance and what lies behind it (the sky, or the farther objects painted there),
    blurred over the object's pixels by `psf_sigma`, is at least that much ("seen" truth).
    """
    order = sorted((k for k, lay in enumerate(layers) if lay is not None), key=lambda k: -layers[k].depth)
    owner = np.zeros((height, width), dtype=np.int16)
    if seen is not None:
        behind, min_contrast, psf_sigma = seen[0].copy(), seen[1], seen[2]
        shown = np.zeros((height, width), dtype=bool)
    clips = {}
    for k in order:
        clip = _clip(layers[k], width, height)
        if clip is None:
            continue
        clips[k] = clip
        img_sl, lay_sl = clip
        mask = layers[k].mask[lay_sl]
        owner[img_sl][mask] = k + 1
        if seen is not None:
            colour = layers[k].radiance[lay_sl][mask]
            contrast = np.abs(colour - behind[img_sl][mask]).max(axis=-1)
            if psf_sigma > 0:
                spread = np.zeros(mask.shape, dtype=np.float32)
                spread[mask] = contrast
                spread = cv2.GaussianBlur(spread, (0, 0), psf_sigma, borderType=cv2.BORDER_CONSTANT)
                contrast = spread[mask]
            shown[img_sl][mask] = contrast >= min_contrast[img_sl][mask]
            behind[img_sl][mask] = colour
    outline = owner.copy() if seen is not None else owner
    if seen is not None:
        owner[~shown] = 0
    rows, moving_labels = [], []
    for k, (img_sl, lay_sl) in sorted(clips.items()):
        obj, layer = objects[k], layers[k]
        amodal = layer.mask[lay_sl]
        if not amodal.any():
            continue
        visible = owner[img_sl] == k + 1
        n_visible = int(visible.sum())
        box = _tight_box(visible if n_visible else amodal, img_sl[1].start, img_sl[0].start)
        rows.append(
            TruthRow(
                id=obj.id,
                class_id=obj.class_id,
                static=obj.static,
                x=box[0],
                y=box[1],
                w=box[2],
                h=box[3],
                visibility=n_visible / layer.area,
                visible_px=n_visible,
                occluded_px=int(amodal.sum()) - int((outline[img_sl] == k + 1).sum()),
            )
        )
        if not obj.static and obj.moving(t):
            moving_labels.append(k + 1)
    return FrameTruth(rows=rows, motion_mask=np.isin(owner, moving_labels))


def _blur_kernel(velocity: np.ndarray, length: float) -> np.ndarray:
    """A normalised line kernel of `length` pixels along `velocity`."""
    half = int(np.ceil(length / 2))
    size = 2 * half + 1
    kernel = np.zeros((size, size), dtype=np.float32)
    d = velocity / np.linalg.norm(velocity) * length / 2
    scale = 1 << 4
    p0 = np.round((np.array([half, half]) - d) * scale).astype(int)
    p1 = np.round((np.array([half, half]) + d) * scale).astype(int)
    cv2.line(kernel, tuple(int(v) for v in p0), tuple(int(v) for v in p1), 1.0, 1, cv2.LINE_AA, shift=4)
    return kernel / kernel.sum()


def _composite(radiance: np.ndarray, layer: Layer, velocity: np.ndarray, blur: float) -> None:
    """Paint `layer` over `radiance` in place, smeared along `velocity` (px/frame) by the shutter time."""
    length = blur * float(np.linalg.norm(velocity))
    colour, alpha = layer.radiance, layer.mask.astype(np.float32)
    x0, y0 = layer.x0, layer.y0
    if length >= 1.0:
        kernel = _blur_kernel(velocity, length)
        pad = kernel.shape[0] // 2
        colour = cv2.filter2D(cv2.copyMakeBorder(colour, pad, pad, pad, pad, cv2.BORDER_CONSTANT), -1, kernel)
        alpha = cv2.filter2D(cv2.copyMakeBorder(alpha, pad, pad, pad, pad, cv2.BORDER_CONSTANT), -1, kernel)
        x0, y0 = x0 - pad, y0 - pad
    smeared = Layer(x0, y0, colour, alpha > 0, layer.depth)
    clip = _clip(smeared, radiance.shape[1], radiance.shape[0])
    if clip is None:
        return
    img_sl, lay_sl = clip
    a = alpha[lay_sl][..., None]
    radiance[img_sl] = radiance[img_sl] * (1.0 - a) + colour[lay_sl]


class SequenceRenderer:
    """Renders frame `t` of a plan: `render(t) -> (rgb uint8, FrameTruth)`, frames in any order."""

    def __init__(self, plan: ScenePlan, truth: str = "silhouette", seen_snr: float = 3.0):
        check_truth(truth, seen_snr)
        self.plan, self.truth_mode, self.seen_snr = plan, truth, float(seen_snr)
        cam, p = plan.camera, plan.params
        reach = np.abs(plan.slew) * plan.num_frames
        self.pad = (int(np.ceil(reach[0])) + 2, int(np.ceil(reach[1])) + 2) if reach.any() else (0, 0)
        sky_rng = np.random.default_rng([*plan.seed, 1])
        self.sky = optics.sky_canvas(
            sky_rng,
            width=cam.width,
            height=cam.height,
            pad=self.pad,
            stars_per_640x480=p.stars,
            psf_sigma=p.psf_sigma_px,
            planet=plan.planet,
            sun_dir=plan.sun_dir,
        )
        self.stray = None
        if plan.glare_uv is not None:
            self.stray = optics.stray_light(
                sky_rng,
                width=cam.width,
                height=cam.height,
                source_uv=plan.glare_uv,
                glare=p.glare,
                flare=p.flare,
            )

    def offset(self, t: int) -> np.ndarray:
        """Image displacement of the world at frame `t` due to camera slew."""
        return self.plan.slew * t

    def layers(self, t: int) -> list[Layer | None]:
        plan, off = self.plan, self.offset(t)
        out = []
        for obj in plan.objects:
            rot, pos = obj.pose(t, plan.camera)
            out.append(
                render_mesh(
                    obj.mesh,
                    rot,
                    pos,
                    plan.camera,
                    sun_dir=plan.sun_dir,
                    sun=plan.params.sun,
                    ambient=plan.params.ambient,
                    offset=(float(off[0]), float(off[1])),
                )
            )
        return out

    def _sky(self, t: int) -> np.ndarray:
        """Radiance (H, W, 3) of the sky in frame `t`, shifted by the camera's slew."""
        cam = self.plan.camera
        return optics.shift_canvas(self.sky, self.pad, self.offset(t), (cam.width, cam.height))

    def seen_reference(self, t: int) -> tuple[np.ndarray, np.ndarray, float]:
        """What the "seen" truth compares each object pixel of frame `t` with: (the sky radiance (H, W, 3)
        behind the objects, median-filtered over 5x5 pixels, which takes out the stars: a black target
        hiding a star is not thereby seen, one crossing a planet is; the (H, W) contrast a pixel needs:
        `seen_snr` times the noise the sensor adds over the background there, sky and stray light, in
        radiance units of this frame's gain; the optics' blur sigma the contrast is spread by)."""
        p, gain = self.plan.params, float(self.plan.exposure[t])
        sky = self._sky(t)
        background = sky if self.stray is None else sky + self.stray
        background_dn = np.clip(background.max(axis=-1) * gain, 0.0, 2.0) * 255.0 + p.black_level_dn
        noise_dn = np.sqrt(background_dn * p.shot_noise**2 + p.read_noise_dn**2)
        min_contrast = (self.seen_snr * noise_dn / (255.0 * gain)).astype(np.float32)
        sky = cv2.medianBlur(np.ascontiguousarray(sky, dtype=np.float32), 5)
        return sky, min_contrast, float(p.psf_sigma_px)

    def truth(self, t: int, layers: list[Layer | None] | None = None) -> FrameTruth:
        cam = self.plan.camera
        return frame_truth(
            self.plan.objects,
            self.layers(t) if layers is None else layers,
            t,
            cam.width,
            cam.height,
            self.seen_reference(t) if self.truth_mode == "seen" else None,
        )

    def render(self, t: int) -> tuple[np.ndarray, FrameTruth]:
        plan, p = self.plan, self.plan.params
        layers = self.layers(t)
        radiance = self._sky(t)
        for k in sorted(
            (k for k, lay in enumerate(layers) if lay is not None), key=lambda k: -layers[k].depth
        ):
            _composite(radiance, layers[k], plan.objects[k].image_velocity(t) + plan.slew, p.motion_blur)
        if self.stray is not None:
            radiance += self.stray
        # a separate stream per frame keeps frames independent of rendering order
        noise_rng = np.random.default_rng([*plan.seed, 2, t])
        rgb = optics.sensor(
            radiance,
            noise_rng,
            gain=float(plan.exposure[t]),
            bloom=p.bloom,
            psf_sigma=p.psf_sigma_px,
            shot_noise=p.shot_noise,
            read_noise_dn=p.read_noise_dn,
            black_level_dn=p.black_level_dn,
            hot_pixels=plan.hot_pixels,
        )
        return rgb, self.truth(t, layers)


def longest_hidden_run(renderer: SequenceRenderer, obj_id: int) -> tuple[int, bool]:
    """(longest run of frames with `obj_id` in the field but fully hidden, whether it is seen after that run)."""
    hidden, seen = [], []
    for t in range(renderer.plan.num_frames):
        row = next((r for r in renderer.truth(t).rows if r.id == obj_id), None)
        hidden.append(row is not None and row.visible_px == 0)
        seen.append(row is not None and row.visible_px > 0)
    best, end, run = 0, -1, 0
    for t, is_hidden in enumerate(hidden):
        run = run + 1 if is_hidden else 0
        if run > best:
            best, end = run, t
    return best, best > 0 and any(seen[end + 1 :])
