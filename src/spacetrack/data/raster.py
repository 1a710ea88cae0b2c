"""Pinhole camera, flat Lambertian + Blinn-Phong shading and triangle rasterisation into layers.

Camera coordinates: x right, y down, z forward (metres); image coordinates: u right, v down (pixels),
pixel (u, v) covering [u, u+1) x [v, v+1). Each mesh renders into a `Layer`: a small window of the image
holding the object's radiance and its exact silhouette mask, the ground truth's source of truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from spacetrack.data.geometry import Mesh

_SHIFT = 4  # fixed-point bits for sub-pixel vertex positions in OpenCV's polygon filling
_NEAR = 1.0  # metres: nothing closer than this to the camera is drawn


@dataclass(frozen=True)
class Camera:
    width: int
    height: int
    focal_px: float

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float) -> Camera:
        return cls(width, height, (width / 2.0) / np.tan(np.radians(hfov_deg) / 2.0))

    @property
    def centre(self) -> np.ndarray:
        return np.array([self.width / 2.0, self.height / 2.0])

    def project(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) camera-frame points (z > 0) to (N, 2) pixel coordinates (u, v)."""
        return self.focal_px * points[:, :2] / points[:, 2:3] + self.centre

    def unproject(self, uv: np.ndarray, depth: float) -> np.ndarray:
        """(2,) pixel position at `depth` metres to a camera-frame point."""
        return np.array([*((np.asarray(uv) - self.centre) * depth / self.focal_px), depth])


@dataclass
class Layer:
    """One object's rendering: `radiance` (h, w, 3) float32 and `mask` (h, w) bool at image offset (x0, y0)."""

    x0: int
    y0: int
    radiance: np.ndarray
    mask: np.ndarray
    depth: float

    @property
    def area(self) -> int:
        """Silhouette pixels, including those outside the image (the unclipped, unoccluded area)."""
        return int(self.mask.sum())


def shade_faces(
    normals: np.ndarray,
    centroids: np.ndarray,
    *,
    albedo: np.ndarray,
    specular: np.ndarray,
    shininess: np.ndarray,
    sun_dir: np.ndarray,
    sun: float,
    ambient: float,
) -> np.ndarray:
    """Radiance (F, 3) of flat faces lit by a distant sun along unit `sun_dir` (towards the sun).

    Lambertian diffuse plus a Blinn-Phong specular lobe; faces turned from the sun get only `ambient`,
    which is 0 by default so the night side is as black as space.
    """
    diffuse = np.clip(normals @ sun_dir, 0.0, None)
    view = -centroids / np.linalg.norm(centroids, axis=1, keepdims=True)
    half = sun_dir + view
    half /= np.linalg.norm(half, axis=1, keepdims=True)
    lobe = np.clip(np.einsum("ij,ij->i", normals, half), 0.0, None) ** shininess
    spec = specular * lobe * (diffuse > 0)
    return sun * (albedo * diffuse[:, None] + spec[:, None]) + ambient * albedo


def render_mesh(
    mesh: Mesh,
    rotation: np.ndarray,
    position: np.ndarray,
    camera: Camera,
    *,
    sun_dir: np.ndarray,
    sun: float,
    ambient: float = 0.0,
    offset: tuple[float, float] = (0.0, 0.0),
) -> Layer | None:
    """Render `mesh` posed by `rotation` (3x3, object to camera) at `position` (m, camera frame).

    `offset` shifts the projection in pixels (camera slew). Returns None when the object is behind the
    near plane or has no visible face.
    """
    verts = mesh.vertices @ rotation.T + position
    if verts[:, 2].min() <= _NEAR:
        return None
    tri = verts[mesh.faces]  # (F, 3, 3)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(normals, axis=1)
    centroids = tri.mean(axis=1)
    front = (np.einsum("ij,ij->i", normals, centroids) < 0) & (norm > 1e-12)
    if not front.any():
        return None
    idx = np.flatnonzero(front)
    normals = normals[idx] / norm[idx, None]
    shading_normals = normals + mesh.normal_jitter[idx] @ rotation.T
    shading_normals /= np.linalg.norm(shading_normals, axis=1, keepdims=True)
    colours = shade_faces(
        shading_normals,
        centroids[idx],
        albedo=mesh.albedo[idx],
        specular=mesh.specular[idx],
        shininess=mesh.shininess[idx],
        sun_dir=sun_dir,
        sun=sun,
        ambient=ambient,
    ).astype(np.float32)

    uv = camera.project(verts) + np.asarray(offset)
    face_uv = uv[mesh.faces[idx]]  # (K, 3, 2)
    x0, y0 = np.floor(face_uv.reshape(-1, 2).min(axis=0)).astype(int) - 1
    x1, y1 = np.ceil(face_uv.reshape(-1, 2).max(axis=0)).astype(int) + 1
    h, w = y1 - y0 + 1, x1 - x0 + 1
    # the centre of pixel (i, j) is at (j + 0.5, i + 0.5): OpenCV fills pixel centres at integer points
    fixed = np.round((face_uv - [x0 + 0.5, y0 + 0.5]) * (1 << _SHIFT)).astype(np.int32)
    order = np.argsort(-centroids[idx, 2], kind="stable")  # painter's algorithm: far faces first
    index = np.zeros((h, w), dtype=np.uint16)
    for k in order:
        cv2.fillConvexPoly(index, fixed[k], int(k) + 1, lineType=cv2.LINE_8, shift=_SHIFT)
    mask = index > 0
    if not mask.any():
        return None
    radiance = np.zeros((h, w, 3), dtype=np.float32)
    radiance[mask] = colours[index[mask] - 1]
    return Layer(int(x0), int(y0), radiance, mask, float(position[2]))
