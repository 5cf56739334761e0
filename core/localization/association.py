"""Associating detections with tracks: the tracks' predicted pixels, Gaussian innovation
costs, the minimum-cost assignment over allowed pairs, and which assigned pairs another track
could take almost as well."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from core.localization._projection import inv2, project_plane
from core.localization.cameras import NetworkCamera

Array = NDArray[np.float64]

# Cost of a forbidden pairing: above any allowed cost, which is clipped below it.
_FORBIDDEN = 1e9
_MAX_COST = 1e8


def largest_variance(C: Array) -> Array:
    """Return the larger eigenvalue of each 2 x 2 covariance C (..., 2, 2)."""
    half = 0.5 * (C[..., 0, 0] - C[..., 1, 1])
    return 0.5 * (C[..., 0, 0] + C[..., 1, 1]) + np.hypot(half, C[..., 0, 1])


def mahalanobis(nu: Array, S: Array) -> tuple[Array, Array]:
    """Return (nu^T S^-1 nu, ln det S), both (...), for nu (..., 2) and S (..., 2, 2)."""
    S_inv, det = inv2(S)
    d2 = np.einsum("...i,...ij,...j->...", nu, S_inv, nu)
    with np.errstate(divide="ignore", invalid="ignore"):
        return d2, np.log(det)


def ambiguous_pairs(
    cost: Array,
    allowed: NDArray[np.bool_],
    rows: NDArray[np.intp],
    cols: NDArray[np.intp],
    margin: float,
) -> NDArray[np.bool_]:
    """Return, for each assigned pair (rows[k], cols[k]), whether another track could take its
    detection almost as likely: that pairing's cost (a negative log-likelihood) within `margin`
    of the pair's. Two bodies that cross stand inside each other's gates; an
    update with a detection that may be the other body's would bend a track towards it and,
    repeated, swap the two."""
    if margin <= 0 or rows.size == 0:
        return np.zeros(rows.size, dtype=bool)
    c = np.where(allowed, cost, np.inf)
    own = c[rows, cols]
    other_track = c[:, cols].copy()
    other_track[rows, np.arange(rows.size)] = np.inf
    return other_track.min(axis=0) - own < margin


def assign_pairs(
    cost: Array, allowed: NDArray[np.bool_]
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Return the (rows, cols) of the minimum-cost assignment using allowed pairs only."""
    rows_any = np.flatnonzero(allowed.any(axis=1))
    cols_any = np.flatnonzero(allowed.any(axis=0))
    if rows_any.size == 0:
        empty = np.zeros(0, dtype=np.intp)
        return empty, empty
    sub_ok = allowed[np.ix_(rows_any, cols_any)]
    sub = np.where(sub_ok, np.clip(cost[np.ix_(rows_any, cols_any)], -_MAX_COST, _MAX_COST), 0.0)
    sub = np.where(sub_ok, sub, _FORBIDDEN)
    r, c = linear_sum_assignment(sub)
    keep = sub_ok[r, c]
    return rows_any[r[keep]], cols_any[c[keep]]


def project_tracks(
    cam: NetworkCamera, xy: Array, h: Array
) -> tuple[Array, Array, NDArray[np.bool_]]:
    """Return the tracks at `xy` (T, 2) projected at each detection's height `h` (D,): pixels
    (T, D, 2), the Jacobians d pixel / d(x, y) (T, D, 2, 2) and whether the camera can see the
    point (T, D): in front and within the field of view. The last matters: outside the field
    of view the distortion polynomial folds points back into the image, where a track could
    take a detection that is not its own."""
    T, D = xy.shape[0], h.size
    u = np.empty((T, D, 2))
    J = np.empty((T, D, 2, 2))
    seen = np.empty((T, D), dtype=bool)
    for value in np.unique(h):
        sel = np.flatnonzero(h == value)
        proj = project_plane(cam, xy, float(value), jacobian=True)
        assert proj.jacobian is not None
        u[:, sel] = proj.pixels[:, None]
        J[:, sel] = proj.jacobian[:, None]
        Xc = np.column_stack([xy, np.full(T, float(value))]) @ cam.R.T + cam.t
        z = np.where(Xc[:, 2] > 1e-6, Xc[:, 2], 1.0)
        r2 = (Xc[:, 0] ** 2 + Xc[:, 1] ** 2) / z**2
        ok = (Xc[:, 2] > 1e-6) & (r2 <= cam.fov_radius**2)
        seen[:, sel] = ok[:, None]
    return u, J, seen
