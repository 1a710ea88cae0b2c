"""Closed triangle meshes of the three target models (the detector's classes), in metres.

Every mesh is closed and its faces wind counter-clockwise seen from outside, so back-face culling gives
the visible surface. Each face carries its own material (RGB albedo, specular strength, shininess), which
is how panels get solar cells and buses get crinkled foil without textures.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull

CLASS_NAMES = ("satellite", "rocket_body", "debris")


@dataclass(frozen=True)
class Mesh:
    """Triangles `faces` (F, 3) into `vertices` (V, 3) metres, with per-face materials."""

    vertices: np.ndarray
    faces: np.ndarray
    albedo: np.ndarray  # (F, 3) RGB reflectance in [0, 1]
    specular: np.ndarray  # (F,) strength of the specular lobe
    shininess: np.ndarray  # (F,) Blinn-Phong exponent
    normal_jitter: np.ndarray  # (F, 3) perturbation added to face normals (crinkled foil)

    @property
    def radius(self) -> float:
        """Bounding radius around the origin, metres."""
        return float(np.linalg.norm(self.vertices, axis=1).max())


def merge(*meshes: Mesh) -> Mesh:
    """One mesh holding all parts (parts must not interpenetrate for painter's ordering to hold)."""
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
    return Mesh(
        vertices=np.concatenate([m.vertices for m in meshes]),
        faces=np.concatenate([m.faces + o for m, o in zip(meshes, offsets, strict=True)]),
        albedo=np.concatenate([m.albedo for m in meshes]),
        specular=np.concatenate([m.specular for m in meshes]),
        shininess=np.concatenate([m.shininess for m in meshes]),
        normal_jitter=np.concatenate([m.normal_jitter for m in meshes]),
    )


def _material(albedo: np.ndarray, specular: float, shininess: float, jitter: float = 0.0, rng=None):
    """Per-face material arrays for (F, 3) `albedo`; `jitter` > 0 crinkles normals and varies albedo."""
    n_faces = len(albedo)
    normal_jitter = np.zeros((n_faces, 3))
    if jitter > 0 and rng is not None:
        normal_jitter = rng.normal(0.0, jitter, size=(n_faces, 3))
        albedo = albedo * rng.uniform(0.85, 1.15, size=(n_faces, 1))
    return np.clip(albedo, 0.0, 1.0), np.full(n_faces, specular), np.full(n_faces, shininess), normal_jitter


def _uniform(n_faces: int, albedo) -> np.ndarray:
    return np.broadcast_to(np.asarray(albedo, dtype=np.float64), (n_faces, 3)).copy()


def _quad_grid(corner: np.ndarray, du: np.ndarray, dv: np.ndarray, nu: int, nv: int):
    """Vertices and CCW triangles of a planar grid spanning corner + [0,1]du + [0,1]dv."""
    s = np.linspace(0.0, 1.0, nu + 1)
    t = np.linspace(0.0, 1.0, nv + 1)
    verts = corner + s[:, None, None] * du + t[None, :, None] * dv
    verts = verts.reshape(-1, 3)
    idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    tris = np.stack([np.stack([a, b, c], -1), np.stack([a, c, d], -1)], axis=2)  # (nu, nv, 2, 3)
    return verts, tris.reshape(-1, 3), tris.shape[0] * tris.shape[1]


def box(
    size, *, albedo, specular=0.2, shininess=20.0, jitter=0.0, rng=None, cells=(1, 1), cell_albedo=None
) -> Mesh:
    """An axis-aligned box of `size` (sx, sy, sz) centred at the origin.

    With `cells` = (nx, ny) the +z face is split into a grid whose cells take `cell_albedo` and whose
    alternate rows are slightly darker: the look of a solar array.
    """
    half = np.asarray(size, dtype=np.float64) / 2.0
    ex, ey, ez = np.diag(half * 2)
    lo = -half
    faces_spec = [  # (corner, du, dv) with du x dv pointing outwards
        (lo + ez, ex, ey),  # +z
        (lo, ey, ex),  # -z
        (lo + ex, ey, ez),  # +x
        (lo, ez, ey),  # -x
        (lo + ey, ez, ex),  # +y
        (lo, ex, ez),  # -y
    ]
    verts, tris, albs = [], [], []
    offset = 0
    for k, (corner, du, dv) in enumerate(faces_spec):
        nu, nv = cells if k == 0 else (1, 1)
        v, t, _ = _quad_grid(corner, du, dv, nu, nv)
        verts.append(v)
        tris.append(t + offset)
        offset += len(v)
        if k == 0 and cell_albedo is not None:
            base = np.asarray(cell_albedo, dtype=np.float64)
            row = np.repeat(np.arange(nu), nv * 2)
            shade = np.where(row % 2 == 0, 1.0, 0.8)[:, None]
            albs.append(base * shade)
        else:
            albs.append(_uniform(len(t), albedo))
    return Mesh(
        np.concatenate(verts),
        np.concatenate(tris),
        *_material(np.concatenate(albs), specular, shininess, jitter, rng),
    )


def cylinder(radius: float, length: float, *, segments=24, albedo, specular=0.4, shininess=30.0) -> Mesh:
    """A capped cylinder along x, centred at the origin."""
    ang = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([np.zeros_like(ang), radius * np.cos(ang), radius * np.sin(ang)], axis=1)
    left = ring + [-length / 2, 0, 0]
    right = ring + [length / 2, 0, 0]
    centres = np.array([[-length / 2, 0, 0], [length / 2, 0, 0]])
    verts = np.concatenate([left, right, centres])
    i = np.arange(segments)
    j = (i + 1) % segments
    side = np.concatenate([np.stack([i, j, segments + j], 1), np.stack([i, segments + j, segments + i], 1)])
    cap_l = np.stack([np.full(segments, 2 * segments), j, i], 1)
    cap_r = np.stack([np.full(segments, 2 * segments + 1), segments + i, segments + j], 1)
    faces = np.concatenate([side, cap_l, cap_r])
    return Mesh(verts, faces, *_material(_uniform(len(faces), albedo), specular, shininess))


def cone(r0: float, r1: float, x0: float, x1: float, *, segments=24, albedo, specular=0.3) -> Mesh:
    """A capped truncated cone along x from radius r0 at x0 to r1 at x1."""
    mesh = cylinder(1.0, 1.0, segments=segments, albedo=albedo, specular=specular)
    v = mesh.vertices.copy()
    left = v[:, 0] < 0
    v[left, 1:] *= r0
    v[~left, 1:] *= r1
    v[:, 0] = np.where(left, x0, x1)
    return Mesh(v, mesh.faces, mesh.albedo, mesh.specular, mesh.shininess, mesh.normal_jitter)


def translate(mesh: Mesh, offset) -> Mesh:
    return Mesh(
        mesh.vertices + np.asarray(offset, dtype=np.float64),
        mesh.faces,
        mesh.albedo,
        mesh.specular,
        mesh.shininess,
        mesh.normal_jitter,
    )


FOIL_GOLD = (0.85, 0.62, 0.22)
FOIL_SILVER = (0.75, 0.75, 0.78)
CELL_BLUE = (0.10, 0.16, 0.38)


def satellite(rng: np.random.Generator) -> Mesh:
    """A box bus wrapped in foil with one or two solar arrays on booms, metres."""
    bus = rng.uniform(1.2, 2.6, size=3)
    foil = FOIL_GOLD if rng.random() < 0.6 else FOIL_SILVER
    parts = [box(bus, albedo=foil, specular=0.9, shininess=40.0, jitter=0.25, rng=rng)]
    span = rng.uniform(2.5, 6.0)
    width = rng.uniform(1.0, 1.8) * min(1.0, bus[2] / 1.2)
    cells = (int(max(2, round(span / 0.6))), int(max(1, round(width / 0.6))))
    sides = (-1, 1) if rng.random() < 0.8 else (1,)
    gap = rng.uniform(0.3, 0.8)
    for side in sides:
        panel = box(
            (span, width, 0.08),
            albedo=(0.8, 0.8, 0.8),
            specular=1.2,
            shininess=80.0,
            cells=cells,
            cell_albedo=CELL_BLUE,
        )
        cx = side * (bus[0] / 2 + gap + span / 2)
        parts.append(translate(panel, (cx, 0, 0)))
        boom = box((gap, 0.12, 0.12), albedo=(0.6, 0.6, 0.6), specular=0.3)
        parts.append(translate(boom, (side * (bus[0] / 2 + gap / 2), 0, 0)))
    if rng.random() < 0.5:
        antenna = cone(0.1, rng.uniform(0.4, 0.8), 0.0, 0.35, segments=16, albedo=(0.9, 0.9, 0.88))
        # point the dish along -z of the bus (towards a typical line of sight)
        rot = np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]], dtype=np.float64)
        dish = Mesh(
            antenna.vertices @ rot.T,
            antenna.faces,
            antenna.albedo,
            antenna.specular,
            antenna.shininess,
            antenna.normal_jitter,
        )
        parts.append(translate(dish, (0, 0, -bus[2] / 2 - 0.01)))
    return merge(*parts)


def rocket_body(rng: np.random.Generator, *, radius=None, length=None) -> Mesh:
    """A spent upper stage: a capped cylinder in bands of white and grey with a nozzle, along x."""
    radius = rng.uniform(0.9, 1.8) if radius is None else radius
    length = rng.uniform(5.0, 10.0) if length is None else length
    bands = int(rng.integers(2, 5))
    edges = np.linspace(-length / 2, length / 2, bands + 1)
    parts = []
    for k in range(bands):
        shade = (0.82, 0.82, 0.80) if k % 2 == 0 else (0.45, 0.45, 0.47)
        seg = cylinder(radius, edges[k + 1] - edges[k], albedo=shade, specular=0.35, shininess=25.0)
        parts.append(translate(seg, ((edges[k] + edges[k + 1]) / 2, 0, 0)))
    nozzle = cone(
        radius * 0.35, radius * 0.75, length / 2 + 0.01, length / 2 + radius * 0.9, albedo=(0.25, 0.22, 0.2)
    )
    parts.append(nozzle)
    return merge(*parts)


def debris(rng: np.random.Generator) -> Mesh:
    """An irregular fragment: the convex hull of random points, flattened or elongated, metres."""
    points = rng.normal(size=(int(rng.integers(8, 18)), 3))
    points *= rng.uniform(0.3, 1.4, size=3)
    hull = ConvexHull(points)
    faces = hull.simplices.copy()
    # orient every face outwards (ConvexHull does not promise a winding)
    centre = points[hull.vertices].mean(axis=0)
    normals = np.cross(points[faces[:, 1]] - points[faces[:, 0]], points[faces[:, 2]] - points[faces[:, 0]])
    inward = np.einsum("ij,ij->i", normals, points[faces[:, 0]] - centre) < 0
    faces[inward] = faces[inward][:, ::-1]
    base = rng.uniform(0.35, 0.8) * np.array(rng.choice([FOIL_SILVER, FOIL_GOLD, (0.6, 0.58, 0.55)]))
    return Mesh(points - centre, faces, *_material(_uniform(len(faces), base), 0.7, 25.0, 0.15, rng))


BUILDERS = {"satellite": satellite, "rocket_body": rocket_body, "debris": debris}


def build(class_name: str, rng: np.random.Generator) -> Mesh:
    """A random instance of `class_name` (one of CLASS_NAMES)."""
    if class_name not in BUILDERS:
        raise ValueError(f"unknown target model {class_name!r}; expected one of {sorted(BUILDERS)}")
    return BUILDERS[class_name](rng)
