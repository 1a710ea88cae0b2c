"""Everything between the scene and the pixel values: sky background, stray light and the sensor.

Radiance is linear, 1.0 being full scale (255 DN) at unit gain. Backgrounds are rendered once per
sequence on a canvas padded for camera slew; the sensor adds gain, blooming, optical blur, shot and read
noise, a black level and hot pixels, then quantises to uint8.
"""

from __future__ import annotations

import cv2
import numpy as np

STAR_TINTS = np.array([[1.0, 1.0, 1.0], [0.8, 0.88, 1.0], [1.0, 0.9, 0.75]], dtype=np.float32)


def sky_canvas(
    rng: np.random.Generator,
    *,
    width: int,
    height: int,
    pad: tuple[int, int],
    stars_per_640x480: int,
    psf_sigma: float,
    planet: dict | None,
    sun_dir: np.ndarray,
) -> np.ndarray:
    """Static background (stars, optional planet limb) on a canvas of (H + 2 pad_y, W + 2 pad_x, 3)."""
    ph, pw = height + 2 * pad[1], width + 2 * pad[0]
    n = int(round(stars_per_640x480 * (pw * ph) / (640 * 480)))
    impulses = np.zeros((ph, pw, 3), dtype=np.float32)
    xs = rng.uniform(0, pw - 1, n)
    ys = rng.uniform(0, ph - 1, n)
    # a steep power law: most stars faint, a few bright enough to saturate
    flux = np.minimum(0.04 * rng.pareto(1.6, n) + 0.04, 6.0).astype(np.float32)
    tint = STAR_TINTS[rng.integers(0, len(STAR_TINTS), n)]
    # bilinear splat keeps sub-pixel positions; the PSF blur below gives each star its profile
    x0, y0 = np.floor(xs).astype(int), np.floor(ys).astype(int)
    fx, fy = (xs - x0).astype(np.float32), (ys - y0).astype(np.float32)
    peak = 2 * np.pi * max(psf_sigma, 0.5) ** 2  # so that a star's peak is about its flux
    for dx, dy, wgt in (
        (0, 0, (1 - fx) * (1 - fy)),
        (1, 0, fx * (1 - fy)),
        (0, 1, (1 - fx) * fy),
        (1, 1, fx * fy),
    ):
        np.add.at(impulses, (y0 + dy, x0 + dx), (flux * wgt * peak)[:, None] * tint)
    sky = cv2.GaussianBlur(impulses, (0, 0), max(psf_sigma, 0.5))
    if planet is not None:
        _draw_planet(sky, planet, pad, sun_dir)
    return sky


def _draw_planet(sky: np.ndarray, planet: dict, pad: tuple[int, int], sun_dir: np.ndarray) -> None:
    """Paint a lit planet disc with clouds and a thin atmosphere over the sky, in place."""
    ph, pw = sky.shape[:2]
    cu, cv = planet["centre"] + np.asarray(pad)
    radius = planet["radius"]
    yy, xx = np.mgrid[0:ph, 0:pw].astype(np.float32)
    nx, ny = (xx - cu) / radius, (yy - cv) / radius
    rho2 = nx**2 + ny**2
    disc = rho2 < 1.0
    nz = -np.sqrt(np.clip(1.0 - rho2, 0.0, 1.0))
    light = np.clip(nx * sun_dir[0] + ny * sun_dir[1] + nz * sun_dir[2], 0.0, None)
    crng = np.random.default_rng(planet["cloud_seed"])
    clouds = np.zeros((ph, pw), dtype=np.float32)
    for scale, amp in ((64, 0.6), (16, 0.3), (4, 0.1)):
        small = crng.random((ph // scale + 2, pw // scale + 2)).astype(np.float32)
        clouds += amp * cv2.resize(small, (pw, ph), interpolation=cv2.INTER_CUBIC)
    cloud = np.clip((clouds - 0.55) * 3.0, 0.0, 1.0)[..., None]
    ocean = np.array([0.04, 0.12, 0.3], dtype=np.float32)
    white = np.array([0.85, 0.87, 0.9], dtype=np.float32)
    surface = (ocean * (1 - cloud) + white * cloud) * light[..., None] * 0.9
    sky[disc] = surface[disc]
    rho = np.sqrt(rho2)
    halo = np.exp(-np.clip(rho - 1.0, 0.0, None) * radius / 6.0) * (rho >= 1.0)
    limb_light = np.clip(nx * sun_dir[0] + ny * sun_dir[1], 0.0, None) / np.maximum(rho, 1e-6)
    sky += (0.35 * halo * limb_light)[..., None] * np.array([0.35, 0.55, 1.0], dtype=np.float32)


def stray_light(
    rng: np.random.Generator, *, width: int, height: int, source_uv: np.ndarray, glare: float, flare: float
) -> np.ndarray:
    """Veiling glare from a bright source at `source_uv` plus flare ghosts along the axis through the centre.

    The ghosts (how many, where along the axis, their size and tint) are drawn from `rng`.
    """
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    diag = np.hypot(width, height)
    dist = np.hypot(xx - source_uv[0], yy - source_uv[1])
    veil = glare * (1.0 / (1.0 + (dist / (0.12 * diag)) ** 2)) ** 1.5
    out = np.repeat(veil[..., None], 3, axis=2) * np.array([1.0, 0.97, 0.9], dtype=np.float32)
    if flare > 0:
        axis = np.array([width / 2, height / 2]) - source_uv
        for _ in range(int(rng.integers(3, 6))):
            cu, cv = source_uv + rng.uniform(0.4, 2.0) * axis
            radius = rng.uniform(0.02, 0.09) * diag
            tint = rng.uniform(0.3, 1.0, size=3).astype(np.float32)
            ring = np.clip(1.0 - np.hypot(xx - cu, yy - cv) / radius, 0.0, 1.0) ** 0.5
            out += (flare * 0.12 * ring)[..., None] * tint
    return out.astype(np.float32)


def shift_canvas(
    canvas: np.ndarray, pad: tuple[int, int], offset: np.ndarray, size: tuple[int, int]
) -> np.ndarray:
    """The (H, W) window of a padded canvas seen when the world is displaced by `offset` pixels."""
    width, height = size
    if not np.any(offset) and pad == (0, 0):
        return canvas.copy()
    m = np.array([[1.0, 0.0, offset[0] - pad[0]], [0.0, 1.0, offset[1] - pad[1]]], dtype=np.float32)
    return cv2.warpAffine(canvas, m, (width, height), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


def sensor(
    radiance: np.ndarray,
    rng: np.random.Generator,
    *,
    gain: float,
    bloom: float,
    psf_sigma: float,
    shot_noise: float,
    read_noise_dn: float,
    black_level_dn: float,
    hot_pixels: np.ndarray,
) -> np.ndarray:
    """Expose, bloom, blur, add noise and quantise a linear radiance image to RGB uint8."""
    img = radiance * np.float32(gain)
    if bloom > 0:
        excess = np.clip(img - 1.0, 0.0, None)
        if excess.any():
            img += bloom * (
                cv2.GaussianBlur(excess, (0, 0), 2.0) + 0.5 * cv2.GaussianBlur(excess, (0, 0), 8.0)
            )
    if psf_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), psf_sigma)
    dn = np.clip(img, 0.0, 2.0) * np.float32(255.0) + np.float32(black_level_dn)
    std = np.sqrt(dn * np.float32(shot_noise**2) + np.float32(read_noise_dn**2))
    dn += std * rng.standard_normal(dn.shape, dtype=np.float32)
    if len(hot_pixels):
        dn[hot_pixels[:, 1], hot_pixels[:, 0]] += 180.0
    return np.clip(np.rint(dn), 0, 255).astype(np.uint8)
