"""Points and plane polygons."""

from __future__ import annotations

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


def _shoelace_terms(polygons: ArrayLike) -> tuple[Array, Array, Array, Array, Array]:
    """Return x, y (..., N), their next vertices x1, y1 and the cross terms x y1 - x1 y."""
    p = np.asarray(polygons, dtype=np.float64)
    x, y = p[..., 0], p[..., 1]
    x1, y1 = np.roll(x, -1, axis=-1), np.roll(y, -1, axis=-1)
    return x, y, x1, y1, x * y1 - x1 * y


def signed_area(polygons: ArrayLike) -> Array:
    """Return the signed areas (...) of polygons (..., N, 2), positive when counter-clockwise.

    The shoelace formula, A = 1/2 sum_i (x_i y_(i+1) - x_(i+1) y_i) (Green's theorem over the
    boundary); each polygon is closed implicitly. Units are those of the vertices, squared."""
    *_, cross = _shoelace_terms(polygons)
    area: Array = 0.5 * cross.sum(axis=-1)
    return area


def area_centroid(polygons: ArrayLike) -> Array:
    """Return the area centroids (..., 2) of simple polygons (..., N, 2), either orientation.

    The shoelace formula's first moments, c = 1 / (6 A) sum_i (p_i + p_(i+1)) (x_i y_(i+1) -
    x_(i+1) y_i); a polygon whose |A| is below 1e-12 (no area to weigh) gets its vertex mean."""
    x, y, x1, y1, cross = _shoelace_terms(polygons)
    a = 0.5 * cross.sum(axis=-1)
    flat = np.abs(a) < 1e-12
    safe = np.where(flat, 1.0, a)
    c = np.stack([((x + x1) * cross).sum(axis=-1), ((y + y1) * cross).sum(axis=-1)], axis=-1)
    centroid: Array = c / (6.0 * safe[..., None])
    if np.any(flat):
        mean = np.asarray(polygons, dtype=np.float64).mean(axis=-2)
        centroid = np.where(flat[..., None], mean, centroid)
    return centroid
