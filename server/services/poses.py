"""Pose conversions at the API boundary (core.geometry's quaternion convention)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from core.geometry.poses import pose_from_quaternion


def pose_from_position_quaternion(
    position: Sequence[float], quaternion_xyzw: Sequence[float]
) -> list[list[float]]:
    """Return the 4x4 rigid transform (row-major lists) with rotation from the unit quaternion
    (x, y, z, w; normalised here) and translation `position` (metres)."""
    q = np.asarray(quaternion_xyzw, dtype=float)
    norm = float(np.linalg.norm(q))
    # A quaternion this short is noise, not a rotation: refuse it rather than amplify it.
    if not np.isfinite(norm) or norm < 1e-9:
        raise ValueError("quaternion_xyzw must have a non-zero norm")
    T: list[list[float]] = pose_from_quaternion(position, q).tolist()
    return T
