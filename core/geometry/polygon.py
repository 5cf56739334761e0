"""Points and plane polygons."""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


def points_in_polygons(points: ArrayLike, polygons: Sequence[ArrayLike]) -> NDArray[np.bool_]:
    """Return inside (M, Z): whether each point (M, 2) lies inside each polygon ((N_z, 2) each).

    The even-odd rule: a horizontal ray from the point crosses the polygon's boundary an odd
    number of times when the point is inside. All edges of all polygons are tested at once.
    A point exactly on an edge may fall either way (a measured position never sits there).
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if not polygons:
        return np.zeros((p.shape[0], 0), dtype=bool)
    rings = [np.asarray(poly, dtype=np.float64).reshape(-1, 2) for poly in polygons]
    a = np.concatenate(rings)
    b = np.concatenate([np.roll(r, -1, axis=0) for r in rings])
    owner = np.repeat(np.arange(len(rings)), [r.shape[0] for r in rings])
    px, py = p[:, 0:1], p[:, 1:2]
    straddles = (a[None, :, 1] > py) != (b[None, :, 1] > py)  # (M, E)
    dy = b[:, 1] - a[:, 1]
    safe = np.where(dy == 0.0, 1.0, dy)
    x_cross = a[None, :, 0] + (py - a[None, :, 1]) * (b[:, 0] - a[:, 0])[None, :] / safe[None, :]
    crosses = straddles & (px < x_cross)
    # Crossings per polygon: (M, E) @ (E, Z), the edges' one-hot owners.
    owners = np.zeros((owner.size, len(rings)), dtype=np.int64)
    owners[np.arange(owner.size), owner] = 1
    counts = crosses.astype(np.int64) @ owners
    return (counts % 2) == 1


def inside_polygon(P: Array, poly: Array) -> NDArray[np.bool_]:
    """Return whether points P (N, 2) lie inside a simple polygon poly (V, 2), by the even-odd
    rule (points_in_polygons); points on an edge may fall either way."""
    inside: NDArray[np.bool_] = points_in_polygons(P, [poly])[:, 0]
    return inside


@functools.lru_cache(maxsize=64)
def _successors(n: int) -> NDArray[np.intp]:
    """Return the index (n,) of each vertex's successor in a polygon of n vertices (read-only:
    kept from one call to the next, as the landmark reader's quadrilaterals ask for it)."""
    nxt = np.roll(np.arange(n), -1)
    nxt.flags.writeable = False
    return nxt


def signed_area(polygon: Array) -> float:
    """Return the signed area of a polygon (N, 2) by the shoelace formula (Gauss's area
    formula): positive when its vertices run counter-clockwise in x right, y up."""
    x, y = polygon[:, 0], polygon[:, 1]
    nxt = _successors(polygon.shape[0])
    return 0.5 * float(x @ y[nxt] - x[nxt] @ y)
