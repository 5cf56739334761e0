"""Rigid transforms T (..., 4, 4) = [[R, t], [0, 1]]: made from a position and a quaternion or
from a floor pose, and inverted. Batch dimensions come first."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.geometry.rotations import quaternion_to_matrix

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
