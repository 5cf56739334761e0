"""A person's body axis fitted to their silhouette in a calibrated camera's image (02 §2).

A blob's lowest pixel is the near edge of the body, about one body radius from its centre
towards the camera, so cameras on different sides disagree by a body diameter.
`locate_body_axis` reports instead the image of one well-defined body point, the foot of the
body's vertical axis (a vertical cylinder, `BodyModel`), with a covariance that covers the body
model's error: see its docstring for the geometry. Any person segmenter can feed it its mask:
the background model (`core.localization.detect.background_model.PersonDetector.detect_bodies`)
does.

Pixel coordinates have their origin at the centre of the top-left pixel (as the renderer).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from core.errors import ConvergenceError, InvalidInput
from core.geometry.camera import undistort_points
from core.geometry.rotations import wrap_angle
from core.localization._projection import project_plane
from core.localization.cameras import NetworkCamera

Array = NDArray[np.float64]
Image = NDArray[Any]


@dataclass(frozen=True)
class BodyModel:
    """The body `locate_body_axis` fits: a vertical cylinder, with the spread of real bodies.

    radius, height (m): the nominal cylinder, an adult's half shoulder width and stature.
    radius_sigma, height_sigma (m): the standard deviations of a person's radius and height
    about them (the priors). shape_sigma (m): how far each edge of a real silhouette (the near
    foot, the half width, the far top of the head) departs from one cylinder's, independently per
    edge. lateral_sigma (m): how far the middle of the silhouette lies beside the body's axis
    (posture, a swinging arm, a bag). edge_sigma (px): the standard deviation of an edge's
    position in the blob, by default the quantisation bound of a binary edge, 1 / sqrt(12).
    axis_height (m): the height of the reported axis point (0: the axis's foot on the floor).
    occlusion_z: the one-sided tests, in standard deviations, that declare foot and head in
    disagreement (one of them hidden) and a side hidden (the blob narrower than the body at its
    range); 2.5 (0.6 % false alarms) because a missed occlusion ruins a fused position while a
    false alarm only widens one camera's covariance. merged_range: how much farther than its
    width says a blob with neither end seen may be (two bodies, one behind the other, make one
    blob about twice as wide as either).

    The defaults are an adult's proportions and a real body's departures from a cylinder. The
    twin's walkers are rigid cylinders: for them shape_sigma = lateral_sigma = 0 is the truth
    (tests/core/localization/test_person_detect.py measures both settings).
    """

    radius: float = 0.2
    height: float = 1.7
    radius_sigma: float = 0.03
    height_sigma: float = 0.1
    shape_sigma: float = 0.03
    lateral_sigma: float = 0.01
    edge_sigma: float = 0.29
    axis_height: float = 0.0
    occlusion_z: float = 2.5
    merged_range: float = 2.0

    def __post_init__(self) -> None:
        for name in ("radius", "height", "radius_sigma", "edge_sigma", "occlusion_z"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InvalidInput(f"BodyModel.{name} must be finite and > 0, got {v}")
        if not (math.isfinite(self.merged_range) and self.merged_range >= 1.0):
            raise InvalidInput(f"BodyModel.merged_range must be >= 1, got {self.merged_range}")
        for name in ("height_sigma", "shape_sigma", "lateral_sigma"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise InvalidInput(f"BodyModel.{name} must be finite and >= 0, got {v}")
        if not (math.isfinite(self.axis_height) and 0 <= self.axis_height <= self.height):
            raise InvalidInput(
                f"BodyModel.axis_height must lie in [0, height], got {self.axis_height}"
            )


Cue = Literal["left", "right", "foot", "head"]


@dataclass(frozen=True)
class BodyDetection:
    """One person reported as the image of a point on the vertical axis of their body.

    pixel (2,): distorted pixel of the axis point at `height` m above the floor; cov (2, 2)
    px^2: its covariance, body-model error included; kind: "person"; bbox (x, y, w, h) and
    area: the blob, pixels. A tracker or `locate_ml` treats the detection as the projection of
    (X, Y, height), (X, Y) the person's centre.

    Diagnostics, from this camera alone: floor_xy (2,) m and floor_cov (2, 2) m^2, the axis's
    floor position (what `pixel` and `cov` encode); bearing (rad, world azimuth of the axis
    seen from the camera) and range (m, horizontal distance from the camera's centre to the
    axis); radius (m), the fitted body radius (from the width when used, else the ends and the
    prior); body_height (m), the height of the far top edge
    (NaN when it was not seen), which tells a person from a low object; cues: the silhouette's
    edges the fit used; foot_hidden: the lowest edge was judged hidden by an occluder (not used);
    sides_hidden: the blob is narrower than the body at its range (a side hidden, the bearing
    widened); ends_disagree: foot and head gave ranges too far apart (one hidden, which is
    unknown: the range spans both).
    """

    pixel: Array
    cov: Array = field(repr=False)
    height: float
    bbox: tuple[int, int, int, int]
    area: int
    floor_xy: Array = field(repr=False)
    floor_cov: Array = field(repr=False)
    bearing: float
    range: float
    radius: float
    body_height: float
    cues: tuple[Cue, ...]
    foot_hidden: bool = False
    sides_hidden: bool = False
    ends_disagree: bool = False
    kind: str = "person"

    @property
    def std(self) -> Array:
        """Standard deviations (2,) of (u, v), pixels."""
        return np.sqrt(np.diag(self.cov))


# The arc test (`_arc_seen`): where it looks, as a fraction of the limbs' azimuth from the axis,
# and the least fraction of a circle's rise (fall) there that the blob's bottom (top) edge must
# show; a straight occluding edge shows none.
_ARC_AT = 0.85
_ARC_MIN = 0.3
# Largest r / D used in asin(r / D) (a body nearly touching the camera's vertical).
_MAX_RATIO = 0.99
# A range equation (c_D, c_r, value, variance): c_D D + c_r r = value.
_Row = tuple[float, float, float, float]
# A blob spanning more than this azimuth around the camera's vertical stands under the camera,
# where the bearing of its axis is undefined.
_MAX_SPAN = math.pi / 2


def _azimuth_slope(camera: NetworkCamera, px: Array, a0: float) -> tuple[Array, Array]:
    """Return, per pixel (N, 2), its ray's world azimuth relative to a0 (rad) and its slope
    d_z / |d_xy| (negative below the horizontal)."""
    try:
        m = undistort_points(px, camera.K, camera.dist)
    except ConvergenceError:
        raise InvalidInput(
            f"camera {camera.name!r}: the blob's pixels cannot be undistorted; check the "
            "camera's distortion coefficients"
        ) from None
    d = np.column_stack([m, np.ones(len(m))]) @ camera.R  # R^T (x, y, 1) per row
    hz = np.hypot(d[:, 0], d[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = d[:, 2] / hz
    return wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - a0), slope


def _gradient_norms(camera: NetworkCamera, px: Array, a0: float) -> tuple[Array, Array]:
    """Return |grad azimuth| and |grad slope| (per pixel) at pixels (N, 2), central differences
    over one pixel."""
    steps = np.array([[0.5, 0.0], [-0.5, 0.0], [0.0, 0.5], [0.0, -0.5]])
    a, s = _azimuth_slope(camera, (px[:, None, :] + steps).reshape(-1, 2), a0)
    a, s = a.reshape(-1, 4), s.reshape(-1, 4)
    ga = np.hypot(wrap_angle(a[:, 0] - a[:, 1]), wrap_angle(a[:, 2] - a[:, 3]))
    gs = np.hypot(s[:, 0] - s[:, 1], s[:, 2] - s[:, 3])
    return ga, gs


def _arc_seen(
    a: Array,
    s: Array,
    cz: float,
    height: float,
    centre: float,
    dist: float,
    radius: float,
    step: float,
) -> bool:
    """Return whether the blob's bottom (height 0) or top (height > 0) edge bends as the body's
    base or top circle does (False: a straight occluding edge, a table top or a lintel, cuts the
    body there).

    With rho the horizontal distance at which a boundary pixel's ray reaches `height`: along
    the base circle's near half the lowest edge's rho grows from D - r in the middle to
    D cos t - sqrt(r^2 - D^2 sin^2 t) at azimuth t from it; along the top circle's far half
    the highest edge's rho falls from D + r to D cos t + sqrt(r^2 - D^2 sin^2 t). At
    t = _ARC_AT beta (beta = asin(r / D), the limbs) the edge must show at least _ARC_MIN of that
    change. a, s: azimuths (relative, rad) and slopes of the boundary pixels; centre: the axis's
    relative azimuth; step: rad per pixel (the windows are at least 1.5 pixels wide). An edge
    with no boundary pixel to judge by at one end is kept.
    """
    if not dist > radius:
        return False
    beta = math.asin(min(radius / dist, _MAX_RATIO))
    t = _ARC_AT * beta
    chord = math.sqrt(max(radius**2 - (dist * math.sin(t)) ** 2, 0.0))
    change = radius - dist * (1.0 - math.cos(t)) - chord
    win = max(0.1 * beta, 1.5 * step)
    sides = [np.abs(a - (centre + side * t)) < win for side in (-1.0, 1.0)]
    if not all(np.any(near) for near in sides):
        return True
    down = s < 0
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = np.where(down, (cz - height) / -s, np.nan)
    if height == 0.0:
        ends = [np.nanmin(np.where(near, rho, np.inf)) for near in sides]
        return float(min(ends) - np.nanmin(rho)) >= _ARC_MIN * change
    ends = [np.nanmax(np.where(near, rho, -np.inf)) for near in sides]
    return float(np.nanmax(rho) - max(ends)) >= _ARC_MIN * change


def _curvature_cov(
    camera: NetworkCamera,
    xy: Array,
    cos_b: float,
    sin_b: float,
    sigma_d: float,
    height: float,
    pixel: Array,
) -> Array:
    """Return the pixel covariance (2, 2) of the projection's curvature along the viewing ray.

    The range along the bearing is the weak direction (metres of spread where the foot is
    hidden), and a floor line's image bends (lens distortion, perspective), so a Gaussian in
    the pixel, linear with J = d pixel / d(X, Y), leaves the true image of the range's spread
    by the second-order term q = a dD^2 / 2. Its variance for dD ~ N(0, sigma_d^2) is
    a a^T sigma_d^4 / 2, with a from the projections at D +- k sigma_d (k = 2):
    a = (p+ + p- - 2 p0) / (k sigma_d)^2. Negligible for a range fixed to centimetres.
    """
    k = 2.0
    step = k * sigma_d * np.array([cos_b, sin_b])
    ends = np.stack([xy + step, xy - step])
    proj = project_plane(camera, ends, height)
    if not np.all(proj.depth > 0):
        return np.zeros((2, 2))
    a = (proj.pixels[0] + proj.pixels[1] - 2.0 * pixel) / (k * sigma_d) ** 2
    return 0.5 * np.outer(a, a) * sigma_d**4


def _solve_range(rows: list[_Row]) -> tuple[Array, Array] | None:
    """Return (theta = (D, r), its covariance) of the weighted least squares over rows
    (c_D, c_r, value, variance), None when the rows do not fix both."""
    A = np.array([r[:2] for r in rows])
    b = np.array([r[2] for r in rows])
    w = 1.0 / np.array([r[3] for r in rows])
    N = A.T @ (w[:, None] * A)
    det = N[0, 0] * N[1, 1] - N[0, 1] * N[1, 0]
    if not det > 1e-12 * (N[0, 0] + N[1, 1]) ** 2:
        return None
    cov = np.array([[N[1, 1], -N[0, 1]], [-N[1, 0], N[0, 0]]]) / det
    return cov @ (A.T @ (w * b)), cov


def locate_body_axis(
    mask: Image,
    camera: NetworkCamera,
    model: BodyModel | None = None,
    *,
    origin: tuple[int, int] = (0, 0),
) -> BodyDetection | None:
    """Return the image of a person's body axis fitted to their silhouette, or None.

    mask (H, W): the person's blob (non-zero pixels), whose pixel [0, 0] is the image pixel
    `origin` (x, y), so a crop around the blob will do; camera: the calibrated camera that took
    the image (a camera node knows its calibration); model: the body (`BodyModel()`).

    Model. The body is a vertical cylinder of centre (X, Y), radius r and height H. Seen from
    the camera's optical centre C, every point of it lies, in plan, in the disc of radius r
    around (X, Y), at horizontal distance D from C. The fit uses four edges of the blob, each an
    extreme over the blob's boundary pixels of a function of the pixel's viewing ray
    (undistorted with the camera's calibration), so none depends on the camera's tilt or lens:

    * the limbs, the least and greatest world azimuth of the rays, a_lo and a_hi (the body's
      right and left edges as the camera sees them): the vertical planes through C tangent to
      the cylinder. By symmetry the axis's bearing is phi = (a_lo + a_hi) / 2 whatever r, H
      and D, and sin((a_hi - a_lo) / 2) = r / D (the width);
    * the foot, the steepest ray: it grazes the base circle's point nearest to C, at horizontal
      distance C_z / |slope| = D - r;
    * the head, the shallowest ray: it grazes the far edge of the top disc, at distance
      (C_z - H) / |slope| = D + r (a ceiling camera sees the top of the head).

    phi comes from the limbs alone; (D, r) by weighted linear least squares on the foot, width
    and head equations and the prior r ~ N(radius, radius_sigma^2), with H = height (its
    spread enters the head's variance as (height_sigma / |slope|)^2, large at oblique views:
    the foot and the width fix D, the head matters without them). With foot and width,
    D = rho_foot + D sin(half width): the foreground margin of the blob (its edges lie up to a
    pixel outside the body's, where a partly covered pixel already passes the threshold)
    shortens rho_foot and widens the width by about the same, and cancels. The reported point
    is (X, Y, axis_height), a point of the body's axis, so cameras on opposite sides agree;
    the blob's lowest pixel is the body's near edge, a radius from the axis towards each camera.

    Robustness. An edge whose extreme pixel touches the image border is cut off and not used;
    with one limb, phi = a_limb +- asin(r / D). A straight occluding edge across the legs (a
    table top) or the head (a lintel) is recognised by the missing arc of the base or top
    circle (`_arc_seen`) and that end is dropped; when foot and head both look whole but
    disagree by more than `occlusion_z` standard deviations, one of them is hidden but which is
    unknown, and the range is the two-point mixture of theirs. An occluder beside the body (a
    door jamb) can only narrow the blob: the width is used for the range only if the blob is
    not narrower than the ends and the prior describe by more than one standard deviation, and
    phi's variance always holds the part of [a_hi - beta, a_lo + beta] (beta = asin(r / D)) that
    the blob leaves open, as a uniform spread. The limbs are long vertical edges, so a body
    partly hidden from below or above keeps them.

    Covariance. Each edge's angle has the variance (edge_sigma |grad f|)^2 of its pixel (f
    the azimuth or the slope, gradient per pixel), plus the body model's errors: shape_sigma
    on each of the foot, width and head equations, lateral_sigma / D on phi, the priors on r
    and H. Then (phi, D) -> (X, Y) = C_xy + D (cos phi, sin phi) (floor_cov) and
    (X, Y) -> pixel through the camera's projection at Z = axis_height, to first order, plus
    the projection's curvature over the range's spread (`_curvature_cov`, which matters where
    the range is weak), so that a tracker's or `locate_ml`'s Gaussian pixel model holds the
    body's floor spread seen through this camera.

    None when the blob is empty, stands under the camera (azimuth span > 90 degrees), or has
    no edge that fixes the range. Raises InvalidInput for a mask that is not 2-D or does not
    fit in the camera's image.
    """
    mdl = model or BodyModel()
    if not isinstance(camera, NetworkCamera):
        raise InvalidInput(f"camera must be a NetworkCamera, got {type(camera).__name__}")
    blob = np.asarray(mask)
    if blob.ndim != 2:
        raise InvalidInput(f"mask must be a 2-D (H, W) array, got shape {blob.shape}")
    ox, oy = int(origin[0]), int(origin[1])
    if camera.image_size is not None:
        width, height = camera.image_size
    elif (ox, oy) == (0, 0):
        height, width = blob.shape
    else:
        raise InvalidInput("a cropped mask (origin != (0, 0)) needs the camera's image_size")
    if ox < 0 or oy < 0 or ox + blob.shape[1] > width or oy + blob.shape[0] > height:
        raise InvalidInput(
            f"mask {blob.shape[::-1]} at origin {(ox, oy)} does not fit in the "
            f"{width} x {height} image"
        )
    sub = (blob != 0).astype(np.uint8)
    contours, _ = cv2.findContours(sub, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE, offset=(ox, oy))
    if not contours:
        return None
    area = int(np.count_nonzero(sub))
    pts = np.concatenate([c.reshape(-1, 2) for c in contours]).astype(np.float64)
    border = (
        (pts[:, 0] <= 0) | (pts[:, 1] <= 0) | (pts[:, 0] >= width - 1) | (pts[:, 1] >= height - 1)
    )
    x0, y0 = pts.min(axis=0).astype(int)
    x1, y1 = pts.max(axis=0).astype(int)
    bbox = (int(x0), int(y0), int(x1 - x0 + 1), int(y1 - y0 + 1))

    cz = float(camera.center[2])
    # Azimuths relative to the blob's middle pixel's (the last row), away from the wrap at pi.
    a, s = _azimuth_slope(camera, np.vstack([pts, pts.mean(axis=0)]), 0.0)
    a0 = float(a[-1])
    a, s = wrap_angle(a[:-1] - a0), s[:-1]
    if not np.all(np.isfinite(a)) or np.ptp(a) > _MAX_SPAN:
        return None
    idx = np.array([np.argmin(a), np.argmax(a), np.argmin(s), np.argmax(s)])
    ga, gs = _gradient_norms(camera, pts[idx], a0)
    ok_lo, ok_hi = not border[idx[0]], not border[idx[1]]
    # The boundary pixels' centres are taken as the edges: the foreground margin this leaves
    # (about a pixel, where a partly covered pixel passes the threshold) cancels between the
    # foot and the width (docstring).
    a_lo, a_hi = float(a[idx[0]]), float(a[idx[1]])
    s_foot, s_head = float(s[idx[2]]), float(s[idx[3]])
    ok_foot = not border[idx[2]] and s_foot < 0 and cz > 0
    ok_head = not border[idx[3]] and s_head < 0 and cz > mdl.height
    es2, sh2 = mdl.edge_sigma**2, mdl.shape_sigma**2
    z_max = mdl.occlusion_z

    # Rows (c_D, c_r, value, variance) of the range equations in (D, r).
    rows: dict[str, _Row] = {"prior": (0.0, 1.0, mdl.radius, mdl.radius_sigma**2)}
    if ok_foot:
        rho = cz / -s_foot
        rows["foot"] = (1.0, -1.0, rho, (cz / s_foot**2 * gs[2]) ** 2 * es2 + sh2)
    if ok_head:
        rho = (cz - mdl.height) / -s_head
        var = ((cz - mdl.height) / s_head**2 * gs[3]) ** 2 * es2
        rows["head"] = (1.0, 1.0, rho, var + (mdl.height_sigma / s_head) ** 2 + sh2)
    half = 0.5 * (a_hi - a_lo)
    var_half = 0.25 * es2 * (ga[0] ** 2 + ga[1] ** 2)
    both = ok_lo and ok_hi and 0 < half < math.pi / 2
    centre = 0.5 * (a_lo + a_hi)
    foot_hidden = head_hidden = False
    if both:
        # A straight occluding edge across the legs (a table top) or the head (a lintel) shows
        # no arc where the base or top circle would: each end is judged at the range it gives.
        step = float(ga.max())
        if "foot" in rows:
            d_foot = rows["foot"][2] + mdl.radius
            foot_hidden = not _arc_seen(a, s, cz, 0.0, centre, d_foot, mdl.radius, step)
        if "head" in rows:
            d_head = rows["head"][2] - mdl.radius
            head_hidden = not _arc_seen(a, s, cz, mdl.height, centre, d_head, mdl.radius, step)
    if foot_hidden:
        del rows["foot"]
    if head_hidden:
        del rows["head"]

    # The width fixes r, and with the foot D = rho_foot + r_width: the blob's foreground
    # margin (its edges lie up to a pixel outside the body's) then cancels between the foot
    # and the sides. An occluder beside the body (a door jamb) can only narrow the blob: a blob
    # narrower than the ends and the prior describe by more than one standard deviation is not
    # used for the range (by more than occlusion_z: `sides_hidden`). r_side is the radius the
    # sides are judged by (from the ends and the prior, not the width).
    r_side = mdl.radius
    sides_hidden = too_wide = False
    extra: list[_Row] = []
    if both:
        base = _solve_range(list(rows.values())) if len(rows) > 1 else None
        d0 = float(base[0][0]) if base is not None else mdl.radius / math.sin(half)
        width_row = (math.sin(half), -1.0, 0.0, (d0 * math.cos(half)) ** 2 * var_half + sh2)
        usable = True
        if base is not None:
            r_side = float(base[0][1])
            c = np.array(width_row[:2])
            sd = math.sqrt(width_row[3] + float(c @ base[1] @ c))
            innov = float(c @ base[0])
            sides_hidden = innov < -z_max * sd
            # Wider than one body at the ends' range: the blob holds more than one body.
            too_wide = innov > z_max * sd
            usable = -sd <= innov and not too_wide
        if usable:
            extra.append(width_row)

    # Legs hidden behind low furniture, or a head behind a lintel, can keep an arc-like edge;
    # then the foot puts the body farther than the head does (occlusion moves the lowest visible
    # edge away from the camera and the highest one towards it). Which end is hidden is then
    # unknown: the range is the two-point mixture of the two.
    fit: tuple[Array, Array] | None = None
    ends_disagree = False
    if "foot" in rows and "head" in rows:
        by_foot = _solve_range([rows["prior"], rows["foot"], *extra])
        by_head = _solve_range([rows["prior"], rows["head"], *extra])
        if by_foot is not None and by_head is not None:
            gap = by_foot[0] - by_head[0]
            sd = math.sqrt(by_foot[1][0, 0] + by_head[1][0, 0])
            if gap[0] > z_max * sd:
                fit = (
                    0.5 * (by_foot[0] + by_head[0]),
                    0.5 * (by_foot[1] + by_head[1]) + 0.25 * np.outer(gap, gap),
                )
                r_side = float(fit[0][1])
                ends_disagree = True
    if fit is None:
        if len(rows) + len(extra) < 2:
            return None
        fit = _solve_range([*rows.values(), *extra])
        if fit is None:
            return None
    theta, cov_dr = fit
    dist, radius = float(theta[0]), float(theta[1])
    if not (dist > 0 and radius > 0):
        return None
    if too_wide or ("foot" not in rows and "head" not in rows):
        # The width alone placed the body: it holds only for one body. A blob with neither end
        # seen is as likely two people side by side, one behind the other (their ends fail the
        # arc tests together), whose width stands for a body up to `merged_range` times as far;
        # a blob wider than one body at the range its ends give holds two, and which body its
        # end belongs to is unknown. The range then spreads over [D, merged_range D]: its far
        # end lies two standard deviations out.
        grow = math.sqrt(cov_dr[0, 0] + (0.5 * (mdl.merged_range - 1.0) * dist) ** 2)
        scale = np.array([grow / math.sqrt(cov_dr[0, 0]), 1.0])
        cov_dr = cov_dr * np.outer(scale, scale)

    # Bearing and its joint covariance with D.
    cov_pd = np.zeros((2, 2))
    cov_pd[1, 1] = cov_dr[0, 0]
    lat2 = (mdl.lateral_sigma / dist) ** 2
    beta = math.asin(min(radius / dist, _MAX_RATIO))
    # The body's azimuths [phi - beta, phi + beta] hold the blob's [a_lo, a_hi], so phi lies in
    # [a_hi - beta, a_lo + beta]: the part of that interval the blob does not fix (nothing when
    # the blob has the full width of a body of radius r_side), taken as uniform, adds to phi's
    # variance. This covers a side hidden by an occluder and a body narrower than the prior.
    missing = max(math.asin(min(r_side / dist, _MAX_RATIO)) - half, 0.0) if both else 0.0
    if both:
        phi = centre
        cov_pd[0, 0] = var_half + lat2 + (2.0 * missing) ** 2 / 12.0
    elif ok_lo or ok_hi:
        sign = 1.0 if ok_lo else -1.0
        g = sign * np.array([-radius / dist, 1.0]) / (dist * math.cos(beta))
        phi = (a_lo if ok_lo else a_hi) + sign * beta
        var_edge = es2 * (ga[0] if ok_lo else ga[1]) ** 2
        cov_pd[0, 0] = var_edge + g @ cov_dr @ g + lat2
        cov_pd[0, 1] = cov_pd[1, 0] = float(g @ cov_dr[:, 0])
    else:
        # Both sides cut by the image border: the middle of what is seen, +- half of it.
        phi = 0.5 * (a_lo + a_hi)
        cov_pd[0, 0] = half**2 + lat2
    bearing = float(wrap_angle(np.array(phi + a0)))
    cb, sb = math.cos(bearing), math.sin(bearing)
    floor_xy = camera.center[:2] + dist * np.array([cb, sb])
    J = np.array([[-dist * sb, cb], [dist * cb, sb]])
    floor_cov = J @ cov_pd @ J.T

    proj = project_plane(camera, floor_xy[None], mdl.axis_height, jacobian=True)
    if not proj.depth[0] > 0:
        return None
    assert proj.jacobian is not None
    Jp = proj.jacobian[0]
    cov_px = Jp @ floor_cov @ Jp.T + _curvature_cov(
        camera, floor_xy, cb, sb, math.sqrt(cov_pd[1, 1]), mdl.axis_height, proj.pixels[0]
    )
    body_height = float(cz + s_head * (dist + radius)) if ok_head else math.nan
    flags: list[tuple[Cue, bool]] = [
        ("left", ok_hi and not sides_hidden),
        ("right", ok_lo and not sides_hidden),
        ("foot", "foot" in rows),
        ("head", "head" in rows),
    ]
    cues = tuple(name for name, ok in flags if ok)
    return BodyDetection(
        pixel=proj.pixels[0],
        cov=cov_px,
        height=mdl.axis_height,
        bbox=bbox,
        area=area,
        floor_xy=floor_xy,
        floor_cov=floor_cov,
        bearing=bearing,
        range=dist,
        radius=radius,
        body_height=body_height,
        cues=cues,
        foot_hidden=foot_hidden,
        sides_hidden=sides_hidden,
        ends_disagree=ends_disagree,
    )
