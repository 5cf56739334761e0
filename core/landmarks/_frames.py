"""Object marks (the blue square frames): located from their edges and read.

Each frame's edge points (undistorted) are assigned to its eight sides (outline and hole,
corners excluded, where blur rounds them) and fitted by lines; the eight corners are the
lines' intersections. The pose minimises the corners' reprojection error, its covariance
propagates the line fits' residual noise to the corners and through the least-squares pose.
All the frames of an image are computed together. The symbol fixes the rotation about the
normal to a quarter turn.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from itertools import pairwise
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from core.geometry.polygon import signed_area
from core.landmarks._detection import LandmarkDetection, make_detection
from core.landmarks._edges import bounding_roi, iso_points
from core.landmarks._lines import Lines, fit_lines, line_corners
from core.landmarks._plane_pose import plane_poses, project_plane, rot_z, rvec_cov
from core.landmarks._symbol import read_symbol, symbol_angle
from core.landmarks._view import ImageView
from core.landmarks.artwork import FRAME_BAND, pattern_layout

Array = NDArray[np.float64]
Image = NDArray[Any]

# The frame's corners (line intersections, ~0.05 px noise) must fit a square in perspective to
# this RMS; more means wrong correspondences or a frame seen edge-on.
MAX_CORNER_RMS_PX = 0.6
# A frame's symbol with modules of 2 px or more is read on a patch with modules of this many
# pixels (never fewer than the image's): its corners only fix the frame's rotation to a quarter
# turn, so a finer patch buys nothing but resampling and decoding time (both cost the patch's
# area). The rings' corners give their rotation and resolve their ambiguity: their patches keep
# 2.5 pixels per image pixel.
FRAME_PATCH_MODULE_PX = 4.0


def _quad(contour: Image) -> Array | None:
    """Return the quadrilateral (4, 2) the contour's hull simplifies to, or None."""
    hull = cv2.convexHull(contour)
    peri = cv2.arcLength(hull, True)
    for eps in (0.02, 0.04, 0.06, 0.08):
        q = cv2.approxPolyDP(hull, eps * peri, True)
        if len(q) == 4:
            return q[:, 0, :].astype(np.float64)
    return None


_NEXT = np.array([1, 2, 3, 0])  # the next corner of a quadrilateral


@dataclass(frozen=True)
class FrameEdges:
    """A blue frame's edge points (N, 2) distorted pixels, each labelled with its side: 0-3
    the outline's, 4-7 the hole's (when its edge was found)."""

    points: Array
    labels: NDArray[np.intp]
    count: int


def find_frame_curves(score: Image, outer: Image, hole: Image) -> FrameCurves | None:
    """Return a blue component's edge curves and their quadrilaterals, or None when its outline
    and hole are not quadrilaterals (not a frame)."""
    if _quad(outer) is None or _quad(hole) is None:
        return None
    roi = bounding_roi(outer, score.shape)
    x0, y0, x1, y1 = roi
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.drawContours(mask, [outer - [x0, y0]], -1, 1, -1)
    cv2.drawContours(mask, [hole - [x0, y0]], -1, 0, -1)
    closed = iso_points(score, roi, mask)
    if not closed:
        return None
    hulls = [cv2.convexHull(c.astype(np.float32)) for c in closed]
    areas = np.array([cv2.contourArea(h) for h in hulls])
    order = np.argsort(-areas)
    chosen = [int(order[0])]
    # The frame's hole: the next boundary, inside, of (1 - 2 band)^2 = 0.58 of its area (an
    # affine view keeps area ratios).
    for k in order[1:]:
        ratio = areas[k] / areas[order[0]]
        inside = cv2.pointPolygonTest(hulls[order[0]], tuple(map(float, closed[k].mean(0))), False)
        if 0.45 < ratio < 0.7 and inside > 0:
            chosen.append(int(k))
            break
    curves = [closed[k] for k in chosen]
    quads: list[Array] = []
    for k in chosen:
        q = _quad(hulls[k])
        if q is None:
            return None
        if signed_area(q) > 0:
            q = q[::-1].copy()
        if quads:
            # Inner corner k: the cyclic order (both quadrilaterals run the same way) that best
            # matches the outer corners shrunk about their centre by the frame's ratio (exact
            # under an affine view; nearest corners fail on a frame seen very obliquely).
            outer_q = quads[0]
            c0 = outer_q.mean(0)
            target = c0 + (1 - 2 * FRAME_BAND) * (outer_q - c0)
            turns = q[(np.arange(4)[:, None] + np.arange(4)) % 4]  # (4 shifts, 4 corners, 2)
            q = turns[int(np.argmin(np.sum((turns - target) ** 2, (1, 2))))]
        quads.append(q)
    return FrameCurves(curves, quads)


@dataclass(frozen=True)
class FrameCurves:
    """A blue frame's edge curves (outline first, then the hole's when found), (N_i, 2)
    distorted pixels, and the quadrilateral (4, 2) each one follows (same cyclic order)."""

    curves: list[Array]
    quads: list[Array]


def frame_sides(frames: list[FrameCurves]) -> list[FrameEdges | None]:
    """Return each frame's edge points labelled with their sides: every curve's points go to
    its own quadrilateral's nearest side, away from the corners (all frames' points at once;
    None for a frame with a side under 3 px)."""
    if not frames:
        return []
    curves = [c for f in frames for c in f.curves]
    Q = np.array([q for f in frames for q in f.quads])  # (curves, 4, 2)
    sizes = np.array([len(c) for c in curves])
    which = np.repeat(np.arange(len(curves)), sizes)  # each point's curve
    pts = np.concatenate(curves)
    side = Q[:, _NEXT] - Q
    L = np.sqrt(np.sum(side * side, -1))  # (curves, 4)
    u = side / np.maximum(L, 1e-12)[..., None]
    margin = np.maximum(1.5, 0.12 * L)
    # Per point and side (N, 4), by coordinate: each curve's values repeated over its points
    # (a repeat, where gathering the (N, 4, 2) arrays costs twice the arithmetic).
    dx = pts[:, :1] - np.repeat(Q[..., 0], sizes, 0)
    dy = pts[:, 1:] - np.repeat(Q[..., 1], sizes, 0)
    ux, uy = np.repeat(u[..., 0], sizes, 0), np.repeat(u[..., 1], sizes, 0)
    s = dx * ux + dy * uy
    dn = np.abs(dy * ux - dx * uy)
    mw = np.repeat(margin, sizes, 0)
    ok = (s > mw) & (s < np.repeat(L, sizes, 0) - mw) & (dn < 3.0)
    dn[~ok] = np.inf
    # The nearest side (the first of equals, as argmin), side by side: numpy's reductions along
    # a last axis of 4 cost ten times the arithmetic.
    near = dn[:, 0]
    best = np.zeros(len(dn), np.intp)
    for k in (1, 2, 3):
        closer = dn[:, k] < near
        best[closer] = k
        near = np.where(closer, dn[:, k], near)
    on = near < np.inf
    # Labels within each frame: 0-3 the outline's sides, 4-7 the hole's.
    first = np.cumsum([0] + [len(f.curves) for f in frames])
    rank = np.concatenate([np.arange(len(f.curves)) for f in frames])
    label = best + 4 * rank[which]
    frame_of = np.repeat(np.arange(len(frames)), [len(f.curves) for f in frames])[which]
    short = np.any(L < 3, 1)
    out: list[FrameEdges | None] = []
    bounds = np.searchsorted(frame_of, np.arange(len(frames) + 1))
    for i, f in enumerate(frames):
        if short[first[i] : first[i + 1]].any():
            out.append(None)
            continue
        sl = slice(bounds[i], bounds[i + 1])
        keep = on[sl]
        out.append(FrameEdges(pts[sl][keep], label[sl][keep], 4 * len(f.curves)))
    return out


def locate_frames(
    ctx: ImageView, edges: list[FrameEdges], ideals: list[Array], size: float
) -> list[LandmarkDetection]:
    """Locate and read frames from their edge points' ideal pixels: the lines, corners and
    poses of all of them computed together."""
    if not edges:
        return []
    starts = np.cumsum([0] + [e.count for e in edges])
    lines, line_ok = fit_lines(
        np.concatenate(ideals),
        np.concatenate([e.labels + o for e, o in zip(edges, starts, strict=False)]),
        int(starts[-1]),
    )
    corners, blocks, corner_ok = line_corners(lines)
    lay = pattern_layout("object", size)
    square = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float)
    obj8 = np.concatenate([square * lay.frame_outer, square * lay.frame_inner])
    span = [slice(int(a), int(b)) for a, b in pairwise(starts)]
    valid = [bool(line_ok[sl].all() and corner_ok[sl].all()) for sl in span]
    # Frames whose hole's edges were found (eight corners), and those with the outline alone.
    poses: dict[int, tuple[Array, Array, float, int]] = {}
    for n in (8, 4):
        idx = [i for i, e in enumerate(edges) if valid[i] and e.count == n]
        found = plane_poses(obj8[:n], [corners[span[i]] for i in idx], ctx.K)
        for i, pose in zip(idx, found, strict=True):
            if pose is not None:
                poses[i] = (*pose, n)
    # The hole's edges disagree with the outline (a frame seen nearly edge-on, its band
    # unresolved): the outline alone.
    redo = [i for i, p in poses.items() if p[2] > MAX_CORNER_RMS_PX and p[3] == 8]
    found = plane_poses(obj8[:4], [corners[span[i]][:4] for i in redo], ctx.K)
    for i, pose in zip(redo, found, strict=True):
        if pose is None:
            del poses[i]
        else:
            poses[i] = (*pose, 4)
    kept = [i for i in sorted(poses) if poses[i][2] <= MAX_CORNER_RMS_PX]
    # (else not a square frame seen in perspective)
    covs: dict[int, Array] = {}
    for n in (8, 4):
        idx = [i for i in kept if poses[i][3] == n]
        if not idx:
            continue
        # Each frame's corners on its lines: its quadrilaterals' blocks on the diagonal.
        JL = np.zeros((len(idx), 2 * n, 2 * n))
        rows: list[int] = []
        for f, i in enumerate(idx):
            first = span[i].start
            rows.extend(range(first, first + n))
            for b in range(n // 4):
                JL[f, 8 * b : 8 * b + 8, 8 * b : 8 * b + 8] = blocks[first // 4 + b]
        # Of the left rotation perturbation, which a turn of the mark frame about its normal
        # leaves unchanged.
        cov = _frame_covariance(
            lines.take(np.array(rows)),
            JL,
            obj8[:n],
            np.array([poses[i][0] for i in idx]),
            np.array([poses[i][1] for i in idx]),
            ctx.K,
        )
        covs.update(zip(idx, cov, strict=True))
    if not kept:
        return []
    outlines = ctx.distort(np.concatenate([corners[span[i]][:4] for i in kept]))
    out = []
    for k, i in enumerate(kept):
        R, t, _, n = poses[i]
        sigma = float(np.mean(lines.sigma[span[i].start : span[i].start + n]))
        outline = outlines[4 * k : 4 * k + 4]
        out.append(_finish(ctx, "object", R, t, covs[i], outline, size, sigma))
    return out


def _frame_covariance(lines: Lines, JL: Array, obj: Array, R: Array, t: Array, K: Array) -> Array:
    """Return the (F, 6, 6) covariances of (left rotation perturbation, t) of F frames' least-
    squares poses (R (F, 3, 3), t (F, 3)) of their n corners obj (n, 2), from their lines'
    parameter variances (lines: F n rows, frame by frame): Sigma_c = J_L Sigma_L J_L^T for the
    corners (JL (F, 2 n, 2 n), from `line_corners`: each corner depends on two lines), then the
    sandwich (A^T A)^-1 A^T Sigma_c A (A^T A)^-1 with A the pose Jacobian of the corners'
    projections."""
    F = len(R)
    var = np.stack([lines.var_phi, lines.var_rho], 1).reshape(F, 1, -1)
    Sc = (JL * var) @ np.swapaxes(JL, 1, 2)
    _, _, Jp = project_plane(obj, R, t, K, jacobian=True)
    assert Jp is not None
    A = Jp.reshape(F, -1, 6)
    At = np.swapaxes(A, 1, 2)
    G = np.linalg.solve(At @ A, At)
    return np.asarray(G @ Sc @ np.swapaxes(G, 1, 2), dtype=np.float64)


def _finish(
    ctx: ImageView,
    kind: str,
    R: Array,
    t: Array,
    cov: Array,
    outline: Array,
    size: float,
    rms: float,
) -> LandmarkDetection:
    """Fix the frame's rotation about its normal from the symbol and read it; cov is of
    (left rotation perturbation, t)."""
    lay = pattern_layout("object", size)
    read = (
        read_symbol(ctx, R, t, lay.frame_inner, lay.qr_side, FRAME_PATCH_MODULE_PX)
        if ctx.decode
        else None
    )
    known = False
    if read is not None and read.psi is not None:
        k = round(read.psi / (math.pi / 2))  # (half to even, as np.round)
        R = R @ rot_z(k * np.pi / 2)
        known = True
    elif ctx.decode:
        psi = symbol_angle(ctx, R, t, lay.qr_side, free=False)
        if psi is not None:
            R = R @ rot_z(psi)
            known = True
    # cov is of the left rotation perturbation, invariant under the turn about z.
    return make_detection(
        ctx, kind, R, t, rvec_cov(R, cov), outline, lay.qr_side, read, known, rms, ()
    )
