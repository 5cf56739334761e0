"""Pose geometry of the twin: look-at rotations, schema poses, rigid boxes."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.geometry.rotations import quaternion_to_matrix
from core.sim.scene import Pose

Array = NDArray[np.float64]


def look_at_rotation(position: ArrayLike, target: ArrayLike) -> Array:
    """Return R_world_camera (3, 3) of an OpenCV camera (x right, y down, z forward) at
    `position` looking at `target`, with image up towards world +Z (no roll)."""
    p = np.asarray(position, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - p
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)


def pose_matrix(pose: Pose) -> tuple[Array, Array]:
    """Return (R_parent_body (3, 3), position (3,)) of a schema Pose."""
    if pose.look_at is not None:
        return look_at_rotation(pose.position, pose.look_at), np.array(pose.position)
    assert pose.quaternion_xyzw is not None
    return quaternion_to_matrix(pose.quaternion_xyzw), np.array(pose.position)


def yaw_matrix(yaw: float) -> Array:
    """Return the rotation (3, 3) by `yaw` radians about Z."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


# Unit box faces: (corner indices counter-clockwise seen from outside, outward normal).
_BOX_FACES = (
    ((1, 2, 6, 5), (1.0, 0.0, 0.0)),
    ((3, 0, 4, 7), (-1.0, 0.0, 0.0)),
    ((2, 3, 7, 6), (0.0, 1.0, 0.0)),
    ((0, 1, 5, 4), (0.0, -1.0, 0.0)),
    ((4, 5, 6, 7), (0.0, 0.0, 1.0)),
    ((0, 3, 2, 1), (0.0, 0.0, -1.0)),
)


def box_faces(
    centre_xy: ArrayLike, size: ArrayLike, yaw: float, z0: float = 0.0
) -> list[tuple[Array, Array]]:
    """Return the 6 faces of a box standing at height z0: [(corners (4, 3), normal (3,))].

    centre_xy (2,) metres, size (3,) = (length along its x, width along its y, height), yaw
    radians about Z; corners are world coordinates, normals point outwards.
    """
    c = np.asarray(centre_xy, dtype=np.float64)
    lx, ly, lz = np.asarray(size, dtype=np.float64)
    sx = np.array([-1, 1, 1, -1, -1, 1, 1, -1]) * lx / 2
    sy = np.array([-1, -1, 1, 1, -1, -1, 1, 1]) * ly / 2
    sz = np.array([0, 0, 0, 0, 1, 1, 1, 1]) * lz + z0
    R = yaw_matrix(yaw)
    corners = np.stack([sx, sy, sz], 1) @ R.T + np.array([c[0], c[1], 0.0])
    return [(corners[list(idx)], R @ np.array(n)) for idx, n in _BOX_FACES]
