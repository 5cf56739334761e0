"""Reference Jacobians of kinematic chains by central differences of their forward kinematics."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from core.geometry.rotations import matrix_to_rotvec


def pose_jacobian_by_differences(
    fk: Callable[[np.ndarray], np.ndarray], q: np.ndarray, h: float
) -> np.ndarray:
    """Return the (6, n) geometric Jacobian of the pose fk(q) (4, 4) at the n joints q by central
    differences of step h: rows 0-2 the position's, rows 3-5 the rotation vector of
    R(q + h e_i) R(q - h e_i)^T, each over 2 h."""
    n = len(q)
    Jn = np.zeros((6, n))
    for i in range(n):
        dq = np.zeros(n)
        dq[i] = h
        Tp, Tm = fk(q + dq), fk(q - dq)
        Jn[:3, i] = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
        Jn[3:, i] = matrix_to_rotvec(Tp[:3, :3] @ Tm[:3, :3].T) / (2 * h)
    return Jn
