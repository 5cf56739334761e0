"""A detector's box as a floor measurement: the foot point (the box's bottom centre) with its
covariance, for the camera node and the service alike.

A person detector (the node's own, Frigate's, a user's) gives an axis-aligned box around a
person. A standing person's feet are at the bottom of the box, so the bottom centre is the image
of a point on the floor (height 0), which the tracker takes like any other pixel measurement
(core.localization.tracking). How well a box's bottom centre marks the feet grows with the box:
the legs' stride, the arms and a detector's jitter all scale with the person's image. The model
is

    sigma_u = max(K_U * w, FLOOR_PX),  sigma_v = max(K_V * h, FLOOR_PX)

for a box w x h pixels, uncorrelated. When a side of the box is cut by the image's edge or by a
mask, the box stops at the cut and not at the person:

* a cut bottom: the feet are not in the image, so the foot is not measured (`measured` False);
  the box can be stored, but it must not give a floor position;
* a cut left or right side: the centre moves by up to half the hidden width; sigma_u is raised
  to half the visible width, which covers a person whose hidden part is as wide as what shows;
* a cut top changes nothing at the feet.

The bottom centre is only the body's near edge, and the box has three more edges that a
camera's geometry can use. `foot_on_axis` fits a standing cylinder (BodyModel: radius and
height with their spreads) to all four edges through the camera's model, so the tracker gets
the foot of the body's axis (where cameras on opposite sides agree) with the fit's covariance,
and drops the ends of a box that do not belong to one standing body: a bottom whose feet the
floor plan's furniture hides, a top raised by a second person behind. On the twin's walkers this
takes the box path's position RMSE from 3-4x to 0.9-1.2x the node's own silhouette fit
(tests/core/localization/test_box_path.py; docs/placement-and-boxes.md has the split of the
error by cause).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_points
from core.errors import InvalidInput
from core.localization._projection import distort_to_pixels, project_plane
from core.localization.cameras import NetworkCamera
from core.localization.detect import BodyModel
from core.localization.ground import PointStatus, locate_monocular
from core.localization.occluders import Occluders, line_of_sight

Array = NDArray[np.float64]

# The sides of a box that can be cut, in the order of the `cut` mask's columns.
BOX_SIDES = ("bottom", "top", "left", "right")


@dataclass(frozen=True)
class BoxNoise:
    """The foot's standard deviation as fractions of the box's width (k_u) and height (k_v),
    never below floor_px (a detector's pixel quantisation and jitter on a small box)."""

    k_u: float = 0.10
    k_v: float = 0.04
    floor_px: float = 1.0


DEFAULT_BOX_NOISE = BoxNoise()


@dataclass(frozen=True)
class FootMeasurement:
    """Foot points of N boxes: pixel (N, 2) distorted px (the bottom centre), cov (N, 2, 2) px^2,
    measured (N,) bool, False where the box's bottom is cut (no floor position from it)."""

    pixel: Array
    cov: Array
    measured: NDArray[np.bool_]


def cut_mask(cuts: Iterable[Iterable[str]]) -> NDArray[np.bool_]:
    """Return the (N, 4) mask of cut sides (columns in BOX_SIDES order) of N lists of side
    names; an unknown name raises InvalidInput."""
    rows = []
    for i, sides in enumerate(cuts):
        row = [False] * len(BOX_SIDES)
        for side in sides:
            if side not in BOX_SIDES:
                raise InvalidInput(
                    f"box {i}: unknown cut side {side!r}; the sides are {', '.join(BOX_SIDES)}"
                )
            row[BOX_SIDES.index(side)] = True
        rows.append(row)
    return np.array(rows, dtype=bool).reshape(-1, len(BOX_SIDES))


def box_foot(
    boxes: ArrayLike,
    cut: ArrayLike | None = None,
    *,
    noise: BoxNoise = DEFAULT_BOX_NOISE,
) -> FootMeasurement:
    """Return the foot point of each box (its bottom centre) with its covariance.

    boxes: (N, 4) or (4,) as (x0, y0, x1, y1) in distorted pixels, x0 < x1 and y0 < y1;
    cut: (N, 4) bool, the sides cut by the image's edge or a mask, columns in BOX_SIDES order
    (bottom, top, left, right) (None: nothing cut); noise: the model of the module docstring.
    """
    try:
        arr = np.asarray(boxes, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"boxes must be numeric, shape (N, 4): {exc}") from None
    b = as_points(arr.reshape(1, -1) if arr.ndim == 1 else arr, 4, "boxes")
    n = b.shape[0]
    if np.any(b[:, 2] <= b[:, 0]) or np.any(b[:, 3] <= b[:, 1]):
        i = int(np.flatnonzero((b[:, 2] <= b[:, 0]) | (b[:, 3] <= b[:, 1]))[0])
        raise InvalidInput(
            f"box {i} is {b[i].tolist()}: a box is (x0, y0, x1, y1) with x0 < x1 and y0 < y1"
        )
    c = np.zeros((n, len(BOX_SIDES)), dtype=bool) if cut is None else np.asarray(cut, dtype=bool)
    if c.shape != (n, len(BOX_SIDES)):
        raise InvalidInput(f"cut must be ({n}, {len(BOX_SIDES)}) booleans, got {c.shape}")
    w = b[:, 2] - b[:, 0]
    h = b[:, 3] - b[:, 1]
    pixel = np.stack([0.5 * (b[:, 0] + b[:, 2]), b[:, 3]], axis=1)
    s_u = np.maximum(noise.k_u * w, noise.floor_px)
    side_cut = c[:, BOX_SIDES.index("left")] | c[:, BOX_SIDES.index("right")]
    s_u = np.where(side_cut, np.maximum(s_u, 0.5 * w), s_u)
    s_v = np.maximum(noise.k_v * h, noise.floor_px)
    cov = np.zeros((n, 2, 2))
    cov[:, 0, 0] = s_u**2
    cov[:, 1, 1] = s_v**2
    measured = ~c[:, BOX_SIDES.index("bottom")]
    return FootMeasurement(pixel=pixel, cov=cov, measured=measured)


@dataclass(frozen=True)
class BoxFit:
    """How `foot_on_axis` fits a body to a box's edges.

    edge_u, edge_v: each edge's standard deviation as fractions of the box's width (left and
    right edges) and height (top and bottom), never below floor_px. chi2_1, chi2_2: the 95 %
    points of the chi-square of 1 and 2 degrees of freedom, the tests of the fit's consistency
    with one end of the box dropped and with all its edges. iterations: Gauss-Newton steps.
    """

    edge_u: float = 0.05
    edge_v: float = 0.02
    floor_px: float = 0.5
    chi2_1: float = 3.84
    chi2_2: float = 5.99
    iterations: int = 8


DEFAULT_BOX_FIT = BoxFit()

# The body a real detector's box is fitted with (foot_on_axis's default). A box drawn around a
# walking person holds the arms and the stride as well as the trunk: half its width is the
# half shoulder breadth (0.2 m, BodyModel's radius) plus what the limbs reach out (a walking
# step is about 0.7 m long, so seen from the side mid-stride the feet are 0.35 m either side
# of the axis; seen from the front, nothing), so between 0.2 and 0.4 m: 0.3 +- 0.1 m. With
# the trunk's 0.2 +- 0.03 m, three real boxes in four from the PETS 2009 clip failed the fit's
# consistency test (wider than any body) and gave no floor position. The stature is a
# person's (1.7 +- 0.1 m). A twin's walker is a rigid cylinder: its box is the trunk's
# (BodyModel()).
DETECTOR_BOX_BODY = BodyModel(radius=0.3, radius_sigma=0.1)

# Points per rim of the cylinder whose image's extremes are its box: at 32 the box of a body
# 0.2 m wide seen from 1 m moves by under 0.1 % of its width between two samplings.
_RIM = 32
# A box's x0, y0, x1, y1 are pixel edges, pixel i spanning [i, i + 1) (detectors' convention:
# a blob of columns i..j has the box i, j + 1); in the camera model's pixels pixel i's centre
# is at i, so the edges lie half a pixel lower there.
_BOX_EDGE_OFFSET = 0.5
# Finite-difference steps of (X, Y, H, r), metres.
_STEP = 1e-4
# Columns of the edges in a box (x0, y0, x1, y1) and in the cut mask (bottom, top, left, right).
_EDGE_OF_SIDE = (3, 1, 0, 2)
# The height above the floor (m) of the point whose line of sight says whether furniture hides
# the feet: a shoe's height, so that the floor under a table's edge is not "hidden".
_FOOT_Z = 0.02


def _cylinder_boxes(camera: NetworkCamera, theta: Array) -> tuple[Array, NDArray[np.bool_]]:
    """Return the boxes (M, 4) of the images of vertical cylinders theta (M, 4) = (X, Y, H, r)
    standing on the floor (the extremes of both rims' images) and whether each lies wholly in
    front of the camera."""
    a = np.linspace(0.0, 2.0 * np.pi, _RIM, endpoint=False)
    ring = np.stack([np.cos(a), np.sin(a)], 1)
    m = theta.shape[0]
    X = np.empty((m, 2 * _RIM, 3))
    X[:, :, :2] = theta[:, None, :2] + theta[:, None, 3:4] * np.concatenate([ring, ring])[None]
    X[:, :_RIM, 2] = 0.0
    X[:, _RIM:, 2] = theta[:, None, 2]
    Xc = X @ camera.R.T + camera.t
    z = Xc[..., 2]
    front = np.all(z > 1e-6, axis=1)
    xy = Xc[..., :2] / np.where(z > 1e-6, z, 1.0)[..., None]
    px = distort_to_pixels(camera, xy.reshape(-1, 2))[0].reshape(m, -1, 2)
    return np.concatenate([px.min(axis=1), px.max(axis=1)], axis=1), front


def _solve_each(a: Array, b: Array) -> Array:
    """Return x (M, n, k) solving a[i] x[i] = b[i] for each of a (M, n, n), b (M, n, k); NaN for
    a system that is singular or not finite (a fit gone off the lens's model: its box then
    fails its test, and the box is not measured)."""
    out = np.full(b.shape, np.nan)
    fine = np.all(np.isfinite(a), axis=(1, 2)) & np.all(np.isfinite(b), axis=(1, 2))
    try:
        out[fine] = np.linalg.solve(a[fine], b[fine])
    except np.linalg.LinAlgError:
        for i in np.flatnonzero(fine):
            try:
                out[i] = np.linalg.solve(a[i], b[i])
            except np.linalg.LinAlgError:
                continue
    return out


def _fit_cylinders(
    camera: NetworkCamera,
    boxes: Array,
    weight: Array,
    start: Array,
    body: BodyModel,
    iterations: int,
) -> tuple[Array, Array, Array, NDArray[np.bool_]]:
    """Return (theta (M, 4) = (X, Y, H, r), its covariance (M, 4, 4), the chi-square (M,) of
    the residuals, in front (M,)) of the Gauss-Newton fit of a standing cylinder to each box's
    edges (M, 4) weighted by `weight` (M, 4) (1 / sigma, 0 for an edge not used), with the
    priors H ~ N(body.height, height_sigma^2), r ~ N(body.radius, radius_sigma^2); start (M, 2)
    the first (X, Y)."""
    m = boxes.shape[0]
    prior = np.array([body.height, body.radius])
    prior_sd = np.array([max(body.height_sigma, 1e-3), body.radius_sigma])
    theta = np.c_[start, np.tile(prior, (m, 1))]
    eye = np.eye(4)

    def residual(th: Array) -> tuple[Array, NDArray[np.bool_]]:
        b, front = _cylinder_boxes(camera, th)
        return np.c_[(b - boxes) * weight, (th[:, 2:] - prior) / prior_sd], front

    def jacobian(th: Array, r: Array) -> Array:
        cols = [(residual(th + _STEP * eye[k])[0] - r) / _STEP for k in range(4)]
        return np.stack(cols, axis=2)  # (M, 6, 4)

    for _ in range(iterations):
        r, _front = residual(theta)
        J = jacobian(theta, r)
        JT = J.transpose(0, 2, 1)
        step = _solve_each(JT @ J + 1e-9 * eye, JT @ r[..., None])[..., 0]
        theta = theta - step
        # A radius must stay a body's: a box too narrow or too wide for one says so by its chi2.
        theta[:, 3] = np.clip(theta[:, 3], 0.25 * body.radius, 4.0 * body.radius)
        theta[:, 2] = np.clip(theta[:, 2], 0.05, None)
        moved = np.abs(step[:, :2])
        if float(np.max(moved[np.isfinite(moved)], initial=0.0)) < 1e-5:
            break
    r, front = residual(theta)
    J = jacobian(theta, r)
    JT = J.transpose(0, 2, 1)
    cov = _solve_each(JT @ J + 1e-12 * eye, np.broadcast_to(eye, J.shape[:1] + eye.shape))
    with np.errstate(over="ignore", invalid="ignore"):  # a diverged fit's chi2 is inf: refused
        chi2: Array = np.sum(r**2, axis=1)
    ok: NDArray[np.bool_] = (
        front & np.all(np.isfinite(theta), axis=1) & np.all(np.isfinite(cov), axis=(1, 2))
    )
    return theta, cov, chi2, ok


def foot_on_axis(
    boxes: ArrayLike,
    foot: FootMeasurement,
    camera: NetworkCamera,
    *,
    cut: ArrayLike | None = None,
    occluders: Occluders | None = None,
    body: BodyModel | None = None,
    fit: BoxFit = DEFAULT_BOX_FIT,
) -> FootMeasurement:
    """Return the feet of `foot` (box_foot of `boxes` (N, 4), seen by `camera`) moved to the
    foot of each body's vertical axis, on the floor, from all the box's edges.

    The body is a vertical cylinder (`body`: radius r, height H with their spreads; by default
    DETECTOR_BOX_BODY, a real walking person's box) standing at (X, Y); its image's box is
    the extremes of its two rims' images through the camera's model (lens included).
    (X, Y, H, r) are fitted by Gauss-Newton least squares to the box's four edges (each with
    sigma `fit.edge_u` w or `fit.edge_v` h) and the priors on H and r, starting from the
    bottom centre's ray on the floor; the covariance of (X, Y) is the fit's, so a box's range
    is as good as its four edges and the priors make it. An edge is not used where `cut`
    (N, 4) bool (BOX_SIDES order; the cut sides `box_foot` was given) says so or where it
    lies on the image's border.

    Ends that do not belong to the body: furniture in front of the legs lifts the bottom edge,
    a second person behind raises the top. So

    * a bottom whose foot point (the near edge of the fitted base, at a shoe's height) is
      hidden from the camera by `occluders` (the floor plan's furniture and walls), for the fit
      with and without the bottom edge, is cut: not measured, as a cut bottom;
    * a fit of all edges beyond its chi-square test (`fit.chi2_2`, 2 degrees of freedom) is
      refitted without the bottom and without the top; the one that passes (`fit.chi2_1`) is
      used, both: their mean, with the gap's spread added (which end is wrong is unknown),
      none: the box is not one standing body and is not measured.

    The pixel reported is the projection of (X, Y, 0) with covariance J cov_XY J^T,
    J = d pixel / d(X, Y). A foot whose bottom centre's ray does not meet the floor in front
    of the camera is not `measured`.
    """
    mdl = body or DETECTOR_BOX_BODY
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    n = b.shape[0]
    pixel, cov, measured = foot.pixel.copy(), foot.cov.copy(), foot.measured.copy()
    c = np.zeros((n, len(BOX_SIDES)), dtype=bool) if cut is None else np.asarray(cut, dtype=bool)
    if c.shape != (n, len(BOX_SIDES)):
        raise InvalidInput(f"cut must be ({n}, {len(BOX_SIDES)}) booleans, got {c.shape}")
    idx = np.flatnonzero(measured)
    if idx.size == 0:
        return FootMeasurement(pixel, cov, measured)
    start = locate_monocular(camera, pixel[idx], 0.0, pixel_cov=cov[idx])
    ok = start.status == PointStatus.OK
    measured[idx[~ok]] = False
    idx = idx[ok]
    if idx.size == 0:
        return FootMeasurement(pixel, cov, measured)
    bx = b[idx] - _BOX_EDGE_OFFSET
    w, h = bx[:, 2] - bx[:, 0], bx[:, 3] - bx[:, 1]
    sd_u = np.maximum(fit.edge_u * w, fit.floor_px)
    sd_v = np.maximum(fit.edge_v * h, fit.floor_px)
    weight = np.stack([1.0 / sd_u, 1.0 / sd_v, 1.0 / sd_u, 1.0 / sd_v], axis=1)
    for side, col in enumerate(_EDGE_OF_SIDE):
        weight[c[idx, side], col] = 0.0
    if camera.image_size is not None:
        width, height = camera.image_size
        # An edge on the image's border (within a pixel) is where the image stops.
        weight[:, :2] *= bx[:, :2] > 0.0
        weight[:, 2] *= bx[:, 2] < width - 1.0
        weight[:, 3] *= bx[:, 3] < height - 1.0
    # Three fits per box at once: all edges, without the bottom, without the top.
    no_bottom, no_top = weight.copy(), weight.copy()
    no_bottom[:, 3] = 0.0
    no_top[:, 1] = 0.0
    m = idx.size
    theta, tcov, chi2, front = _fit_cylinders(
        camera,
        np.tile(bx, (3, 1)),
        np.concatenate([weight, no_bottom, no_top]),
        np.tile(start.point[ok, :2], (3, 1)),
        mdl,
        fit.iterations,
    )
    used = np.concatenate([weight, no_bottom, no_top]) > 0
    # Residuals: the used edges and the two priors; unknowns: X, Y, H, r.
    dof = used.sum(axis=1) + 2 - 4
    # Fewer edges than unknowns and priors leave nothing to test (dof <= 0).
    limit = np.select([dof == 1, dof == 2], [fit.chi2_1, fit.chi2_2], np.inf)
    passes = (chi2 <= limit) & front
    th_a, th_b, th_t = theta[:m], theta[m : 2 * m], theta[2 * m :]
    c_a, c_b, c_t = tcov[:m], tcov[m : 2 * m], tcov[2 * m :]
    pass_a, pass_b, pass_t = passes[:m], passes[m : 2 * m], passes[2 * m :]
    # An end not used at all leaves nothing to drop: its "without" fit is the full one.
    pass_b &= weight[:, 3] > 0
    pass_t &= weight[:, 1] > 0
    hidden = np.zeros(m, dtype=bool)
    if occluders is not None and len(occluders):
        for th in (th_a, th_b):
            u = th[:, :2] - camera.center[:2]
            u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-9)
            near = np.c_[th[:, :2] - th[:, 3:4] * u, np.full(m, _FOOT_Z)]
            hidden |= ~line_of_sight(camera.center[None], near, occluders)[0]
        hidden &= weight[:, 3] > 0
    gap = th_b - th_t
    mixed = 0.5 * (c_b + c_t) + 0.25 * gap[:, :, None] * gap[:, None, :]
    both = pass_b & pass_t
    xy = np.select(
        [pass_a[:, None], both[:, None], pass_b[:, None], pass_t[:, None]],
        [th_a[:, :2], 0.5 * (th_b + th_t)[:, :2], th_b[:, :2], th_t[:, :2]],
        th_a[:, :2],
    )
    cxy = np.select(
        [pass_a[:, None, None], both[:, None, None], pass_b[:, None, None], pass_t[:, None, None]],
        [c_a[:, :2, :2], mixed[:, :2, :2], c_b[:, :2, :2], c_t[:, :2, :2]],
        c_a[:, :2, :2],
    )
    good = (pass_a | pass_b | pass_t) & ~hidden & front[:m]
    measured[idx[~good]] = False
    keep = idx[good]
    if keep.size:
        proj = project_plane(camera, xy[good], 0.0, jacobian=True)
        assert proj.jacobian is not None
        J = proj.jacobian
        pixel[keep] = proj.pixels
        c = J @ cxy[good] @ J.transpose(0, 2, 1)
        c = 0.5 * (c + c.transpose(0, 2, 1))  # symmetric to the last bit, as the tracker asks
        cov[keep] = c
        # A foot measured along one direction only (a flat fit's covariance) is no floor
        # position: the tracker takes positive definite covariances.
        det = c[:, 0, 0] * c[:, 1, 1] - c[:, 0, 1] ** 2
        flat = ~(det > 1e-12 * (c[:, 0, 0] + c[:, 1, 1]) ** 2)
        bad = ~(proj.depth > 0) | flat
        measured[keep[bad]] = False
    return FootMeasurement(pixel, cov, measured)
