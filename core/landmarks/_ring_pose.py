"""A signpost's pose from its rings' ellipses: the two candidates of the circles' two-fold
ambiguity, their covariances, the evidence for each (the rings' centre, the symbol, the
vertical-wall prior) and the decision (core.landmarks.ambiguity).

The centre's image is the eigenvector of the pencil of the two conics (not an ellipse centre,
which perspective biases); the plane normal has two candidates from the outer conic; the
distance follows from the known radii.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from core.errors import DegenerateConfiguration
from core.landmarks._detection import LandmarkDetection, make_detection
from core.landmarks._plane_pose import rot_z, rvec_cov
from core.landmarks._rings import RingFit
from core.landmarks._symbol import (
    NOMINAL_MODULES,
    SymbolRead,
    read_symbol,
    square_fit,
    symbol_angle,
)
from core.landmarks._view import ImageView
from core.landmarks.ambiguity import (
    DECIDED_PROBABILITY,
    PoseHypothesis,
    covering_covariance,
    probabilities,
)
from core.landmarks.artwork import pattern_layout
from core.landmarks.conics import (
    circle_distance,
    circle_normals,
    concentric_centre,
    conic_matrix,
    conic_points,
)

Array = NDArray[np.float64]

_UNKNOWN_ANGLE_VAR = np.pi**2 / 3  # rotation about the normal uniform on (-pi, pi]
# The rings' two poses (core.landmarks.ambiguity): the decoder's symbol corners are taken to
# be within this many modules (standard deviation; zxing-cpp and OpenCV place them from the
# finder patterns' module edges), and a wall within this angle of vertical for the mounting
# prior (the wall's plumb and the head's level, radians).
SYMBOL_CORNER_SD = 0.5
WALL_TILT_SD = math.radians(2.0)


def locate_signpost(
    ctx: ImageView, rf: RingFit, cands: _Candidates, size: float
) -> LandmarkDetection | None:
    """Locate and read a signpost from its ellipses and candidate poses."""
    outline = ctx.distort(conic_points(rf.fits[0].C, _OUTLINE_ANGLES))
    return _finish_rings(ctx, rf, cands, outline, size)


_OUTLINE_ANGLES = np.linspace(0, 2 * np.pi, 36, endpoint=False)


def _ring_pose(
    Q0: Array, Qn: Array, radius: float | Array
) -> tuple[Array, tuple[Array, Array], Array]:
    """Return (centre ray m (..., 3), the two candidate normals (..., 3), their depth factors
    (..., 2)) from the normalised conics (..., 3, 3) of the outer edge (its radius known: one,
    or one per pair (...)) and the innermost one: centre from the pencil of the two, normals
    and depth from the outer one."""
    m = concentric_centre(Q0, Qn)
    na, nb = circle_normals(Q0)
    # The outer edge alone gives the distance: it has the white page outside and the widest
    # band inside, while blur merges the inner edges with their neighbours (gaps of 0.05 of
    # the size) once the rings are small in the image, shrinking their contours.
    depths = np.stack(
        [np.asarray(circle_distance(Q0, n, m, radius), dtype=np.float64) for n in (na, nb)], -1
    )
    return m, (na, nb), depths


@dataclass(frozen=True)
class _Candidates:
    m: Array
    normals: tuple[Array, Array]
    depths: Array
    cov: tuple[Array, Array]  # (6, 6) of (rotation about camera axes, translation), per candidate
    # log-likelihood of each candidate from the rings' centre: the pencil centre against the
    # centre the candidate predicts (the pole of its vanishing line with respect to the outer
    # conic), Gaussian in their difference (its noise model in ring_candidates).
    centre_loglik: Array


def ring_candidates(rfs: list[RingFit], K: Array) -> list[_Candidates | None]:
    """Return each signpost's candidates (None where its conics are degenerate): the poses of
    all signposts' nominal and perturbed conic pairs in one batch."""
    if not rfs:
        return []
    # The pose, then the first-order propagation of both conics' covariances (sigma points
    # along their principal axes), ignoring the rotation about the normal (added later from
    # the symbol): per signpost the nominal pair first, then each perturbed one.
    w, U = np.linalg.eigh(np.array([f.cov for rf in rfs for f in (rf.fits[0], rf.fits[-1])]))
    batches = [
        _sigma_pairs(rf, K, w[2 * i : 2 * i + 2], U[2 * i : 2 * i + 2]) for i, rf in enumerate(rfs)
    ]
    sizes = [len(b[0]) for b in batches]
    radii = np.repeat([rf.radii[0] for rf in rfs], sizes)
    skip = (DegenerateConfiguration, np.linalg.LinAlgError)
    try:
        ms, (pa, pb), dps = _ring_pose(
            np.concatenate([b[0] for b in batches]), np.concatenate([b[1] for b in batches]), radii
        )
    except skip:
        # One signpost's conics are degenerate: each on its own.
        out: list[_Candidates | None] = []
        for rf, b in zip(rfs, batches, strict=True):
            try:
                out.append(_candidates(rf, K, *b, None))
            except skip:
                out.append(None)
        return out
    ends = np.cumsum(sizes).tolist()
    return [
        _candidates(rf, K, *b, [a[i - len(b[0]) : i] for a in (ms, pa, pb, dps)])
        for rf, b, i in zip(rfs, batches, ends, strict=True)
    ]


def _sigma_pairs(rf: RingFit, K: Array, w: Array, U: Array) -> tuple[Array, Array, Array]:
    """Return a signpost's normalised conic pairs (outer, innermost) (S, 3, 3) each, the
    nominal pair first, then each sigma point of either conic's covariance (eigenvalues w (2,
    6), eigenvectors U (2, 6, 6)) with the other nominal, and the points of the fit each one
    perturbs (S,) (0 for the nominal)."""
    pair = (rf.fits[0], rf.fits[-1])
    Q0 = K.T @ pair[0].C @ K
    Qn = K.T @ pair[1].C @ K
    sigma: list[Array] = []
    for k, f in enumerate(pair):
        # The conic's scale direction has no variance (numerically ~0): skipped.
        keep = w[k] > 1e-9 * w[k, -1]
        coeffs = _coeffs6(f.C) + np.sqrt(w[k, keep])[:, None] * U[k].T[keep]
        sigma.append(K.T @ conic_matrix(coeffs) @ K)
    n0, n1 = len(sigma[0]), len(sigma[1])
    Q0s = np.concatenate([Q0[None], sigma[0], np.broadcast_to(Q0, (n1, 3, 3))])
    Qns = np.concatenate([Qn[None], np.broadcast_to(Qn, (n0, 3, 3)), sigma[1]])
    n_pts = np.repeat([0.0, float(pair[0].n), float(pair[1].n)], [1, n0, n1])
    return Q0s, Qns, n_pts


def _candidates(
    rf: RingFit,
    K: Array,
    Q0s: Array,
    Qns: Array,
    n_pts: Array,
    poses: list[Array] | None,
) -> _Candidates:
    """Return a signpost's two candidate poses, their covariances and their centre evidence
    from its conic pairs (_sigma_pairs) and their poses (ms, pa, pb, dps of _ring_pose; None:
    computed here)."""
    r0 = rf.radii[0]
    skip = (DegenerateConfiguration, np.linalg.LinAlgError)
    if poses is not None:
        ms, pa, pb, dps = poses
    else:
        try:
            ms, (pa, pb), dps = _ring_pose(Q0s, Qns, r0)
        except skip:
            # The nominal pair or one sigma point is degenerate (a conic near the limit): the
            # nominal alone (raising if it is the one), then the other sigma points one at a
            # time.
            _ring_pose(Q0s[0], Qns[0], r0)
            good = [0]
            for i in range(1, len(Q0s)):
                try:
                    _ring_pose(Q0s[i], Qns[i], r0)
                except skip:
                    continue
                good.append(i)
            Q0s, n_pts = Q0s[good], n_pts[good]
            ms, (pa, pb), dps = _ring_pose(Q0s, Qns[good], r0)
    m, normals, depths = ms[0], (pa[0], pb[0]), dps[0]
    # What the conics' covariances leave out: a deformation of an edge curve moves its conic's
    # centre by about the fit's RMS residual in any direction (pixels, to normalised units).
    floor = np.eye(2) * (rf.fits[0].rms ** 2 + rf.fits[-1].rms ** 2) / (K[0, 0] * K[1, 1])
    # Both candidates j at once (leading axis). Match each perturbed candidate to candidate j
    # by its normal; one-sided difference of (rotation of the normal, centre).
    nj = np.array(normals)  # (2, 3)
    first = nj @ pa.T >= nj @ pb.T  # (2, sigma points)
    n_p = np.where(first[..., None], pa, pb)
    n_p[:, 0] = nj
    d_p = np.where(first, dps[:, 0], dps[:, 1])
    a, b = nj[:, None, :], n_p[:, 1:]
    dv = np.empty((2, len(ms) - 1, 6))
    # (the cross product nj x n_p written out: numpy's costs tens of microseconds)
    dv[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    dv[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    dv[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    dv[..., 3:] = d_p[:, 1:, None] * ms[1:] - depths[:, None, None] * m
    covs = np.swapaxes(dv, 1, 2) @ dv
    # The centre's evidence: r = pencil centre - pole of the vanishing line n (normalised
    # coordinates), nominal and at each sigma point (its covariance, first order). The edge
    # points' errors are taken as fully correlated along each curve (what limits them is
    # systematic: the blur of bands a pixel or two wide, the pixel grid's phase, the lens
    # model), so each fit's covariance is scaled by its number of points: its conic is then as
    # uncertain as its own RMS residual, not that over sqrt(points).
    pole = np.linalg.solve(Q0s, n_p[..., None])[..., 0]
    r = ms[:, :2] - pole[..., :2] / pole[..., 2:3]  # (2, sigma points, 2)
    dr = (r[:, 1:] - r[:, :1]) * np.sqrt(n_pts[1:])[:, None]
    S = np.swapaxes(dr, 1, 2) @ dr + floor
    logdet = np.linalg.slogdet(S)[1]
    rn = r[:, 0]
    maha = np.sum(rn * np.linalg.solve(S, rn[..., None])[..., 0], 1)
    # When even the better candidate misses the centre by more than its noise (chi-square of
    # 2 degrees of freedom above its mean), the noise is larger than modelled (an edge curve
    # that is two merged edges, a band the blur has deformed): the scale is estimated from
    # that candidate's misfit (the Birge ratio), so the evidence is weighed by the noise the
    # image shows.
    scale = max(1.0, float(np.min(maha)) / 2.0)
    loglik = -0.5 * maha / scale - 0.5 * logdet
    return _Candidates(m, normals, depths, (covs[0], covs[1]), loglik)


def _coeffs6(C: Array) -> Array:
    return np.array([C[0, 0], 2 * C[0, 1], C[1, 1], 2 * C[0, 2], 2 * C[1, 2], C[2, 2]])


def _rotation(n: Array, psi: float) -> Array:
    """Return R = [x y z] with z = n and x the camera's x axis projected on the plane, turned by
    psi about z."""
    n0, n1, n2 = (float(v) for v in n)
    if abs(n0) > 0.95:
        ex = np.array([-n1 * n0, 1.0 - n1 * n1, -n1 * n2])  # the y axis, projected
    else:
        ex = np.array([1.0 - n0 * n0, -n0 * n1, -n0 * n2])
    x0 = ex / math.sqrt(float(ex @ ex))
    c, s = math.cos(psi), math.sin(psi)
    # y0 = n x x0; x = cos psi x0 + sin psi y0; then n x x (cross products written out: numpy's
    # is tens of microseconds on 3-vectors).
    y0 = np.array([n1 * x0[2] - n2 * x0[1], n2 * x0[0] - n0 * x0[2], n0 * x0[1] - n1 * x0[0]])
    x = c * x0 + s * y0
    y = np.array([n1 * x[2] - n2 * x[1], n2 * x[0] - n0 * x[2], n0 * x[1] - n1 * x[0]])
    return np.column_stack([x, y, n])


def _finish_rings(
    ctx: ImageView, rf: RingFit, cands: _Candidates, outline: Array, size: float
) -> LandmarkDetection | None:
    lay = pattern_layout("signpost", size)
    poses = [
        (_rotation(n, 0.0), d * cands.m) for n, d in zip(cands.normals, cands.depths, strict=True)
    ]
    half = lay.ring_radii[-1]
    # One read is enough to place the symbol's corners (below); the second candidate's patch is
    # read only when the first does not decode.
    reads: list[SymbolRead | None] = [None, None]
    if ctx.decode:
        for k, (R, t) in enumerate(poses):
            reads[k] = read_symbol(ctx, R, t, half, lay.qr_side)
            if reads[k] is not None:
                break
    # Each candidate's log-likelihood: the rings' centre, then the symbol and the mounting
    # prior when there are (core.landmarks.ambiguity).
    loglik = cands.centre_loglik.copy()
    # 1. The symbol: its corners, read under either candidate, are rays from the camera; laid on
    # each candidate's plane they form a square only on the right one (the wrong plane shears
    # it). The candidate whose rectification decoded is not evidence by itself: near the
    # decoding limit the sheared patch sometimes reads where the right one does not.
    read_any = next((r for r in reads if r is not None and r.corners is not None), None)
    if read_any is not None and read_any.corners is not None:
        R0, t0 = poses[reads.index(read_any)]
        rays = read_any.corners @ R0[:, :2].T + t0
        fits = []
        for n, (R, t) in zip(cands.normals, poses, strict=True):
            P3 = rays * ((n @ t) / (rays @ n))[:, None]
            fits.append(square_fit(((P3 - t) @ R)[:, :2]))
        if any(f is not None for f in fits):
            for j, fit in enumerate(fits):
                if fit is None:  # the corners out of order on this plane: not the symbol's
                    loglik[j] = -np.inf
                    continue
                # The squareness residual (RMS over the 4 corners, in half sides) in modules
                # (half side = NOMINAL_MODULES / 2 of them), 4 residual degrees of freedom
                # (8 coordinates, a similarity fitted), corners SYMBOL_CORNER_SD modules.
                res = fit[1] * NOMINAL_MODULES / 2
                loglik[j] += -0.5 * 4 * res * res / SYMBOL_CORNER_SD**2
                reads[j] = SymbolRead(
                    read_any.text, None, fit[0], read_any.var_psi, fit[1], read_any.module_px
                )
    # 2. The vertical-wall prior: the normal horizontal, within WALL_TILT_SD and the
    # candidate's own uncertainty across it.
    if ctx.up is not None:
        for j, n in enumerate(cands.normals):
            e = math.asin(min(abs(float(n @ ctx.up)), 1.0))
            a = np.cross(n, ctx.up)
            var = WALL_TILT_SD**2 + float(a @ cands.cov[j][:3, :3] @ a) / max(
                1.0 - float(n @ ctx.up) ** 2, 1e-6
            )
            loglik[j] += -0.5 * e * e / var - 0.5 * math.log(var)
    if not np.any(np.isfinite(loglik)):
        return None
    prob = probabilities(loglik)
    order = [int(np.argmax(prob)), 1 - int(np.argmax(prob))]
    decided = prob[order[0]] >= DECIDED_PROBABILITY
    hyps: list[tuple[Array, Array, Array, SymbolRead | None, bool]] = []
    for rank, j in enumerate(order):
        R, t = poses[j]
        read = reads[j]
        psi_known = False
        var_psi = _UNKNOWN_ANGLE_VAR
        if read is not None and read.psi is not None:
            R = R @ rot_z(read.psi)
            psi_known = True
            var_psi = read.var_psi
        elif ctx.decode and read is None and (rank == 0 or not decided):
            psi = symbol_angle(ctx, R, t, lay.qr_side, free=True)
            if psi is not None:
                R = R @ rot_z(psi)
                psi_known = True
                var_psi = (1.0 / NOMINAL_MODULES) ** 2
        cov_theta = cands.cov[j].copy()
        n = cands.normals[j]
        cov_theta[:3, :3] += var_psi * np.outer(n, n)
        hyps.append((R, t, cov_theta, read, psi_known))
    T = [np.eye(4), np.eye(4)]
    for k, (R, t, _, _, _) in enumerate(hyps):
        T[k][:3, :3], T[k][:3, 3] = R, t
    # Of the left perturbation (the candidates' own), for the covering covariance.
    left = tuple(PoseHypothesis(T[k], hyps[k][2], float(prob[j])) for k, j in enumerate(order))
    R, t, cov_theta, read, psi_known = hyps[0]
    if not decided:
        cov_theta = covering_covariance(left)
    hypotheses = tuple(
        PoseHypothesis(h.T, rvec_cov(h.T[:3, :3], h.cov), h.probability) for h in left
    )
    cov = rvec_cov(R, cov_theta)
    rms = float(np.mean([f.rms for f in rf.fits]))
    return make_detection(
        ctx, "signpost", R, t, cov, outline, lay.qr_side, read, psi_known, rms, hypotheses
    )
