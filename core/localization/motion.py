"""The constant-velocity motion model of a body on the floor, state (x, y, vx, vy): its
transition and the process noise of white acceleration."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


def cv_transition(dt: float) -> Array:
    """Return F(dt) (4, 4) of the constant-velocity model on (x, y, vx, vy): x <- x + dt vx."""
    F = np.eye(4)
    F[0, 2] = F[1, 3] = dt
    return F


def cv_process_noise(dt: float, q: float) -> Array:
    """Return Q(dt) (4, 4), m^2, m^2/s, m^2/s^2, of white acceleration of density q (m^2/s^3).

    Q = integral_0^dt F(s) G q G^T F(s)^T ds with G = [0 I]^T, which per axis is
    q [[dt^3/3, dt^2/2], [dt^2/2, dt]] (Bar-Shalom, Li & Kirubarajan 2001, sec. 6.2.2).
    """
    Q = np.zeros((4, 4))
    a, b, c = q * dt**3 / 3.0, q * dt**2 / 2.0, q * dt
    Q[0, 0] = Q[1, 1] = a
    Q[0, 2] = Q[2, 0] = Q[1, 3] = Q[3, 1] = b
    Q[2, 2] = Q[3, 3] = c
    return Q
