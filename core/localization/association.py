"""Associating detections with tracks: Gaussian innovation costs, the minimum-cost assignment
over allowed pairs, and which assigned pairs another track could take almost as well."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from core.localization._projection import inv2

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
