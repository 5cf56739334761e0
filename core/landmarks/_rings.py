"""Signposts' red rings: their edge curves matched to the rings' edges and the ellipses their
pose uses (the outer edge and the innermost that fits)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from core.errors import ConvergenceError, DegenerateConfiguration
from core.landmarks._edges import SCORE_THRESHOLD, bounding_roi, iso_points
from core.landmarks._view import ImageView
from core.landmarks.artwork import RING_RADII, pattern_layout
from core.landmarks.conics import ConicFit, fit_ellipse

Array = NDArray[np.float64]
Image = NDArray[Any]


@dataclass(frozen=True)
class RingFit:
    """A signpost's ellipses its pose uses (the outer edge first, the innermost last) and the
    radii (metres) of the circles they are the images of."""

    fits: tuple[ConicFit, ...]
    radii: tuple[float, ...]


@dataclass(frozen=True)
class RingEdges:
    """A signpost's edge curves (distorted pixels, all stacked in `points`) and their sizes
    (square root of their hulls' areas)."""

    points: Array
    lengths: list[int]
    sizes: Array


def _hull_area(p: Array) -> float:
    """Return the area (pixels^2) of the convex hull of points p (N, 2), from the points on a
    1/256-pixel lattice (OpenCV's integer hull takes two thirds of its floating-point one's
    time; the area moves by at most 3.5e-5 of itself on the 204 ring edges of 26 rendered
    frames, where it only sizes the curve against the rings' radii, at 4.5 % tolerance)."""
    q = np.rint(p * 256.0).astype(np.int32)
    return float(cv2.contourArea(cv2.convexHull(q))) / 65536.0


def ring_edges(score: Image, outer: Image) -> RingEdges | None:
    """Return a red component's edge curves, or None when its outline is not an ellipse's."""
    if len(outer) < 8:
        return None
    _, (ea, eb), _ = cv2.fitEllipse(outer)
    if ea <= 0 or eb <= 0 or cv2.contourArea(outer) < 0.85 * np.pi * ea * eb / 4:
        return None
    roi = bounding_roi(outer, score.shape)
    x0, y0, x1, y1 = roi
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.drawContours(mask, [outer - [x0, y0]], -1, 1, -1)
    mask &= (score[y0:y1, x0:x1] > SCORE_THRESHOLD).astype(np.uint8)
    iso = [c for c in iso_points(score, roi, mask) if len(c) >= 12]
    if not iso:
        return None
    sizes = np.array([np.sqrt(_hull_area(c)) for c in iso])
    return RingEdges(np.concatenate(iso), [len(c) for c in iso], sizes)


@dataclass(frozen=True)
class RingCurves:
    """A signpost's edge curves (distorted pixels), the ring edge each one matches ((curve,
    edge index in RING_RADII), largest curve first), the outer curve's size, the curves' ideal
    pixels undistorted so far, and the ellipses fitted so far (None: not an ellipse)."""

    distorted: list[Array]
    matched: list[tuple[int, int]]
    ref: float
    ideal: dict[int, Array] = field(default_factory=dict)
    fits: dict[int, ConicFit | None] = field(default_factory=dict)

    def first_choices(self) -> list[int]:
        """Return the curves a signpost's pose tries first: the largest matched one and the
        smallest."""
        if not self.matched:
            return []
        ks = [self.matched[0][0], self.matched[-1][0]]
        return ks[:1] if ks[0] == ks[1] else ks

    def fit(self, ctx: ImageView, k: int) -> ConicFit | None:
        if k not in self.fits:
            try:
                if k not in self.ideal:
                    self.ideal[k] = ctx.undistort(self.distorted[k])
                self.fits[k] = fit_ellipse(self.ideal[k])
            except (DegenerateConfiguration, ConvergenceError):
                self.fits[k] = None
        return self.fits[k]


def ring_curves(edges: RingEdges) -> RingCurves:
    """Return a signpost's edge curves matched to the ring edges."""
    ends = np.cumsum(edges.lengths).tolist()
    curves = [edges.points[a:b] for a, b in zip([0, *ends[:-1]], ends, strict=True)]
    sizes = edges.sizes
    order = np.argsort(-sizes)
    ref = sizes[order[0]]
    # Each ring edge's curve (the largest one whose size ratio to the outer edge matches it).
    ratios = (sizes[order] / ref).tolist()
    matched: list[tuple[int, int]] = []
    for k, ratio in zip(order.tolist(), ratios, strict=True):
        miss = [abs(ratio - r / RING_RADII[0]) for r in RING_RADII]
        j = miss.index(min(miss))
        if miss[j] <= 0.045 and all(j != i for _, i in matched):
            matched.append((k, j))
    return RingCurves(curves, matched, float(ref))


def ring_fit(ctx: ImageView, rc: RingCurves, size: float) -> RingFit | None:
    """Return a signpost's ellipses its pose uses, from its matched edge curves (None when they
    do not fit)."""
    lay = pattern_layout("signpost", size)
    matched, ref = rc.matched, rc.ref
    # The pose needs only the outer edge (normal, distance, centre) and the innermost one that
    # fits (the centre from the pencil of the two).
    fits: list[ConicFit] = []
    radii: list[float] = []
    for n, (k, j) in enumerate(matched):
        fit = rc.fit(ctx, k)
        if fit is None:
            continue
        if j != 0:
            return None
        fits.append(fit)
        radii.append(lay.ring_radii[0])
        matched = matched[n + 1 :]
        break
    if not fits:
        return None
    centre0 = fits[0].centre
    for k, j in matched[::-1]:
        fit = rc.fit(ctx, k)
        if fit is None:
            continue
        if np.linalg.norm(fit.centre - centre0) <= 0.2 * ref:
            fits.append(fit)
            radii.append(lay.ring_radii[j])
            break
    if len(fits) < 2:
        return None
    return RingFit(tuple(fits), tuple(radii))
