"""The straight edges of a blue frame: total least-squares lines of its edge points, and the
corners where they meet with their Jacobians on the lines' parameters (what the corners'
covariance propagates)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Lines:
    """Lines normal . x = rho, one row each."""

    normal: Array  # (L, 2) unit
    rho: Array  # (L,)
    centroid: Array  # (L, 2)
    var_phi: Array  # (L,)
    var_rho: Array  # (L,) of rho at the centroid
    sigma: Array  # (L,) residual RMS, pixels

    def take(self, rows: slice | NDArray[np.intp]) -> Lines:
        return Lines(*(getattr(self, f)[rows] for f in self.__dataclass_fields__))


def fit_lines(p: Array, label: NDArray[np.intp], count: int) -> tuple[Lines, Array]:
    """Return the total least-squares lines of the points p (N, 2) of each label 0..count-1,
    each with one 3-sigma outlier pass, and whether each had the 4 points it needs (count,)."""
    ok = np.ones(count, bool)
    # Coordinate by coordinate, each line's values gathered by `take`: numpy's fancy indexing of
    # (count, 2) rows and its sums along a last axis of 2 cost ten times the arithmetic.
    x, y = p.T.copy()
    stats = None
    for _ in range(2):
        n_pts = np.bincount(label, minlength=count).astype(np.float64)
        ok &= n_pts >= 4
        n_pts = np.maximum(n_pts, 1)
        cx = np.bincount(label, x, count) / n_pts
        cy = np.bincount(label, y, count) / n_pts
        dx, dy = x - cx.take(label), y - cy.take(label)
        S = np.empty((count, 2, 2))
        S[:, 0, 0] = np.bincount(label, dx * dx, count)
        S[:, 0, 1] = S[:, 1, 0] = np.bincount(label, dx * dy, count)
        S[:, 1, 1] = np.bincount(label, dy * dy, count)
        # The normal: the eigenvector of the scatter matrix's smaller eigenvalue.
        _, V = np.linalg.eigh(S)
        r = dx * V[:, 0, 0].take(label) + dy * V[:, 1, 0].take(label)
        s = np.sqrt(np.bincount(label, r * r, count) / np.maximum(n_pts - 2, 1))
        keep = np.abs(r) <= (3 * np.maximum(s, 0.05)).take(label)
        stats = (cx, cy, V, s)
        if keep.all():
            break
        x, y, label = x[keep], y[keep], label[keep]
    assert stats is not None
    cx, cy, V, s = stats
    ax, ay = V[:, 0, 1].take(label), V[:, 1, 1].take(label)
    along = (x - cx.take(label)) * ax + (y - cy.take(label)) * ay
    spread = np.bincount(label, along * along, count)
    used = np.maximum(np.bincount(label, minlength=count), 1)
    s = np.maximum(s, 0.02)  # marching squares quantises; never claim better than 0.02 px
    normal = V[:, :, 0]
    lines = Lines(
        normal,
        normal[:, 0] * cx + normal[:, 1] * cy,
        np.stack([cx, cy], -1),
        s * s / np.maximum(spread, 1e-9),
        s * s / used,
        s,
    )
    return lines, ok


def line_corners(lines: Lines) -> tuple[Array, Array, Array]:
    """Return the corners (n, 2) of the quadrilaterals of lines 4 i .. 4 i + 3 (corner k of
    each at lines k - 1 and k), each quadrilateral's Jacobian (n / 4, 8, 8) of its corners on
    its lines' (phi, rho) (corners and lines in order, x and y, phi and rho interleaved; a
    corner depends on its own quadrilateral's lines only), rho measured at each line's
    centroid (so phi and rho are uncorrelated): with A x = rho (rows the normals),
    dx/drho_i = A^-1 e_i and dx/dphi_i = A^-1 e_i (n_i^perp . (c_i - x)); and whether each
    corner exists (n,) (its two lines not parallel)."""
    count = len(lines.rho)
    k = np.arange(count)
    a = (k // 4) * 4 + (k - 1) % 4  # the previous side of the same quadrilateral
    na, nk = lines.normal[a], lines.normal[k]
    det = na[:, 0] * nk[:, 1] - na[:, 1] * nk[:, 0]
    ok = np.abs(det) > 1e-12
    det = np.where(ok, det, 1.0)
    # A^-1 of A = [na; nk]: columns (nk_y, -nk_x) / det and (-na_y, na_x) / det.
    Ai = (
        np.stack([np.stack([nk[:, 1], -na[:, 1]], 1), np.stack([-nk[:, 0], na[:, 0]], 1)], 1)
        / det[:, None, None]
    )
    x = np.einsum("nij,nj->ni", Ai, np.stack([lines.rho[a], lines.rho[k]], 1))
    perp = np.stack([-lines.normal[:, 1], lines.normal[:, 0]], 1)
    # Per quadrilateral q: J[q, corner, xy, line, (phi, rho)], lines numbered within it.
    J = np.zeros((count // 4, 4, 2, 4, 2))
    q, corner = k // 4, k % 4
    for col, idx in ((0, a), (1, k)):
        lever = np.sum(perp[idx] * (lines.centroid[idx] - x), 1)
        J[q, corner, :, idx % 4, 0] = Ai[:, :, col] * lever[:, None]
        J[q, corner, :, idx % 4, 1] = Ai[:, :, col]
    return x, J.reshape(count // 4, 8, 8), ok
