"""Hartley normalisation of point sets (Hartley & Zisserman, 2nd ed., alg. 4.2)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


def hartley_normalization(points: Array) -> tuple[Array, Array]:
    """Return (T (3x3), normalised points (N, 2)): centroid at the origin, mean distance sqrt(2).

    T maps homogeneous input points to the normalised ones. Raises ZeroDivisionError-free: a set
    whose points all coincide gets scale 1 (the caller's degeneracy check rejects it).
    """
    c = points.mean(axis=0)
    d = points - c
    mean_dist = float(np.mean(np.sqrt(np.sum(d * d, axis=1))))
    s = np.sqrt(2.0) / mean_dist if mean_dist > 0 else 1.0
    T = np.array([[s, 0.0, -s * c[0]], [0.0, s, -s * c[1]], [0.0, 0.0, 1.0]])
    return T, d * s
