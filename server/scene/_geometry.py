"""Small geometry for drawing the scene: poses as quaternions, frusta from K, floor polygons
(checked and triangulated here; their areas and centroids are core.geometry.polygon's)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import InvalidInput
from core.geometry.polygon import signed_area
from core.geometry.rotations import matrix_to_quaternion, quaternion_to_matrix

Array = NDArray[np.float64]

# A camera whose intrinsics are unknown is drawn with this vertical field of view; 60 degrees is
# typical of the wide lenses used on ceiling cameras, and the frustum is greyed anyway.
DEFAULT_VERTICAL_FOV = math.radians(60.0)

# How far a pose's rotation may be from orthonormal (max |R^T R - I|) before it is refused:
# poses that went through JSON keep ~1e-15; 1e-6 still accepts poses stored as float32.
_ORTHONORMAL_TOL = 1e-6


@dataclass(frozen=True)
class Pose:
    """A rigid transform as viser takes it: unit quaternion (w, x, y, z) and translation (m)."""

    wxyz: tuple[float, float, float, float]
    position: tuple[float, float, float]


@dataclass(frozen=True)
class Frustum:
    """A symmetric viewing frustum: vertical field of view (rad) and aspect width / height."""

    fov: float
    aspect: float


def quaternion_from_matrix(R: ArrayLike) -> Array:
    """Return the unit quaternion (w, x, y, z), w >= 0, of a 3x3 rotation matrix: viser's order
    of core.geometry's (x, y, z, w) quaternion, renormalised since a pose may be stored as
    float32 (_ORTHONORMAL_TOL)."""
    q = matrix_to_quaternion(R)
    out: Array = q[[3, 0, 1, 2]] / np.linalg.norm(q)
    return out


def matrix_from_quaternion(wxyz: ArrayLike) -> Array:
    """Return the 3x3 rotation matrix of a quaternion in viser's (w, x, y, z) order (normalised
    first)."""
    return quaternion_to_matrix(np.asarray(wxyz, dtype=np.float64)[[1, 2, 3, 0]])


def pose_from_transform(T_world_camera: object, name: str = "T_world_camera") -> Pose:
    """Return the Pose of a 4x4 rigid transform; raise InvalidInput if it is not one (or not a
    matrix at all: whatever the caller was given is checked here)."""
    try:
        T = np.asarray(T_world_camera, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"{name} must be a 4x4 numeric matrix: {exc}") from None
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InvalidInput(f"{name} must be a finite 4x4 matrix, got shape {T.shape}")
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], rtol=0.0, atol=1e-12):
        raise InvalidInput(f"{name} must have last row [0, 0, 0, 1], got {T[3].tolist()}")
    R = T[:3, :3]
    err = float(np.max(np.abs(R.T @ R - np.eye(3))))
    if err > _ORTHONORMAL_TOL or np.linalg.det(R) <= 0.0:
        raise InvalidInput(
            f"{name}[:3, :3] must be a rotation (orthonormal, det +1); |R^T R - I| = {err:.2e}"
        )
    q = quaternion_from_matrix(R)
    return Pose(
        wxyz=(float(q[0]), float(q[1]), float(q[2]), float(q[3])),
        position=(float(T[0, 3]), float(T[1, 3]), float(T[2, 3])),
    )


def frustum_from_intrinsics(K: ArrayLike | None, width: int, height: int) -> Frustum:
    """Return the symmetric frustum of a width x height camera with calibration matrix K.

    fov = 2 atan(height / (2 fy)) (pinhole, Hartley & Zisserman eq. 6.4); the principal point
    offset is not drawn, since viser's frustum is symmetric. Without K, DEFAULT_VERTICAL_FOV.
    """
    if width <= 0 or height <= 0:
        raise InvalidInput(f"image size must be positive, got {width} x {height}")
    aspect = float(width) / float(height)
    if K is None:
        return Frustum(DEFAULT_VERTICAL_FOV, aspect)
    try:
        k = np.asarray(K, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"K must be a 3x3 numeric matrix: {exc}") from None
    if k.shape != (3, 3) or not np.all(np.isfinite(k)) or k[1, 1] <= 0.0:
        raise InvalidInput(f"K must be a finite 3x3 matrix with fy > 0, got shape {k.shape}")
    return Frustum(2.0 * math.atan2(float(height), 2.0 * float(k[1, 1])), aspect)


def as_xy_points(points: object, name: str) -> Array:
    """Return `name`'s [x, y] points as an (N, 2) float array (N may be 0); raise InvalidInput
    for anything else. The caller checks their count and that they are finite."""
    try:
        p = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"{name} must be a list of [x, y] points: {exc}") from None
    if p.size == 0:
        return np.zeros((0, 2))
    if p.ndim != 2 or p.shape[1] != 2:
        raise InvalidInput(f"{name} must be a list of [x, y] points, got shape {p.shape}")
    return p


def as_polygon(points: object, name: str) -> Array:
    """Return a floor polygon as an (N, 2) float array, N >= 3; raise InvalidInput otherwise
    (whatever the caller was given is checked here)."""
    try:
        p = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"{name} must be a list of [x, y] points: {exc}") from None
    if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 3 or not np.all(np.isfinite(p)):
        raise InvalidInput(f"{name} must be at least 3 finite [x, y] points, got shape {p.shape}")
    if np.allclose(p[0], p[-1]):  # a closed ring repeats its first vertex
        p = p[:-1]
    return p


def triangulate_polygon(polygon: Array) -> NDArray[np.int64]:
    """Return (N - 2, 3) counter-clockwise vertex indices triangulating a simple polygon.

    Ear clipping (Eberly, "Triangulation by ear clipping", 2002): O(N^2), fine for rooms with
    tens of corners. Works for concave rooms (an L-shaped living room); self-intersecting input
    gives a fan over what is left rather than failing, since the fill is only decoration.
    """
    n = len(polygon)
    order = list(range(n)) if signed_area(polygon) >= 0 else list(range(n - 1, -1, -1))
    tris: list[tuple[int, int, int]] = []

    def cross(o: Array, a: Array, b: Array) -> float:
        return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))

    guard = 0
    while len(order) > 3 and guard < n * n:
        guard += 1
        m = len(order)
        for i in range(m):
            ia, ib, ic = order[i - 1], order[i], order[(i + 1) % m]
            a, b, c = polygon[ia], polygon[ib], polygon[ic]
            if cross(a, b, c) <= 1e-15:  # reflex or degenerate corner: not an ear
                continue
            inside = False
            for j in order:
                if j in (ia, ib, ic):
                    continue
                p = polygon[j]
                if cross(a, b, p) >= 0 and cross(b, c, p) >= 0 and cross(c, a, p) >= 0:
                    inside = True
                    break
            if not inside:
                tris.append((ia, ib, ic))
                del order[i]
                break
        else:
            break  # no ear found: self-intersecting input; fan the remainder
    for i in range(1, len(order) - 1):
        tris.append((order[0], order[i], order[i + 1]))
    return np.array(tris, dtype=np.int64).reshape(-1, 3)
