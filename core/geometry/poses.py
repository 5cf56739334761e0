"""Rigid transforms T (..., 4, 4) = [[R, t], [0, 1]]: made from a position and a quaternion or
from a floor pose, checked, inverted and compared. Batch dimensions come first."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import InvalidInput
from core.geometry.rotations import matrix_to_rotvec, quaternion_to_matrix

Array = NDArray[np.float64]


def pose_from_quaternion(position: ArrayLike, q_xyzw: ArrayLike) -> Array:
    """Return the rigid transforms (..., 4, 4) with translation `position` (..., 3) and the
    rotation of the quaternions (..., 4) in (x, y, z, w) order (normalised first)."""
    R = quaternion_to_matrix(q_xyzw)
    T = np.zeros((*R.shape[:-2], 4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = np.asarray(position, dtype=np.float64)
    T[..., 3, 3] = 1.0
    return T


def invert_pose(T: ArrayLike) -> Array:
    """Return the inverses (..., 4, 4) of rigid transforms T (..., 4, 4): [R^T, -R^T t]."""
    a = np.asarray(T, dtype=np.float64)
    out = np.zeros_like(a)
    Rt = np.swapaxes(a[..., :3, :3], -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -(Rt @ a[..., :3, 3:4])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def planar_pose(xyt: ArrayLike) -> Array:
    """Return the rigid transforms (..., 4, 4) of floor poses (..., 3) = (x, y, theta): a turn by
    theta (rad) about Z and a translation (x, y, 0) (T_world_body of a body on the floor)."""
    b = np.asarray(xyt, dtype=np.float64)
    c, s = np.cos(b[..., 2]), np.sin(b[..., 2])
    T = np.zeros((*b.shape[:-1], 4, 4))
    T[..., 0, 0], T[..., 0, 1], T[..., 1, 0], T[..., 1, 1] = c, -s, s, c
    T[..., 2, 2] = T[..., 3, 3] = 1.0
    T[..., 0, 3], T[..., 1, 3] = b[..., 0], b[..., 1]
    return T


def as_pose(T: ArrayLike, name: str = "T") -> Array:
    """Return T as a finite (..., 4, 4) float array with a rotation block; raise InvalidInput."""
    try:
        a = np.asarray(T, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"{name} must be a numeric 4x4 pose: {exc}") from None
    if a.ndim < 2 or a.shape[-2:] != (4, 4):
        raise InvalidInput(f"{name} must have shape (..., 4, 4), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InvalidInput(f"{name} contains NaN or infinite values")
    R = a[..., :3, :3]
    ortho = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(initial=0.0)
    if (
        ortho > 1e-6
        or np.any(np.linalg.det(R) < 0)
        or np.any(np.abs(a[..., 3, :] - [0, 0, 0, 1]) > 0)
    ):
        raise InvalidInput(
            f"{name} must be a rigid transform: an orthonormal rotation block with det +1 and a "
            "last row (0, 0, 0, 1)"
        )
    return a


def pose_error(T: ArrayLike, T_target: ArrayLike) -> tuple[Array, Array]:
    """Return (position error (...,) metres, rotation error (...,) radians) between poses: the
    distance between their origins and the angle of R^T R_target."""
    a = np.asarray(T, dtype=np.float64)
    b = np.asarray(T_target, dtype=np.float64)
    dp = np.linalg.norm(a[..., :3, 3] - b[..., :3, 3], axis=-1)
    rel = np.swapaxes(a[..., :3, :3], -1, -2) @ b[..., :3, :3]
    dr = np.linalg.norm(matrix_to_rotvec(rel), axis=-1)
    return dp, dr
