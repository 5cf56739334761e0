"""Points and plane polygons."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


def inside_polygon(P: Array, poly: Array) -> NDArray[np.bool_]:
    """Return whether points P (N, 2) lie inside a simple polygon poly (V, 2), by the even-odd
    rule (a ray to +x crosses the boundary an odd number of times); points on an edge may fall
    either way."""
    x, y = P[:, 0:1], P[:, 1:2]
    a, b = poly, np.roll(poly, -1, axis=0)
    cross = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xi = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return np.asarray(np.sum(cross & (x < xi), axis=1) % 2 == 1)
