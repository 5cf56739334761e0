"""Targets in camera images: the robot's coloured top marker and people (02 §2).

Robot marker. The image is segmented in HSV (hue within `hue_tolerance` of the marker's hue,
saturation and value above their floors) and the connected blobs are tried from the largest to
the smallest: the first whose area, position, fill (no hole), solidity and elliptic outline are
those of a disc's image is the marker, so a larger red thing (a signpost's rings on a wall, a
ring being no disc) cannot hide it. Its centre is the centroid of a *soft* membership weight
over a window around the blob: each pixel's colour is projected on the axis from the local
background colour (median of a ring around the blob) to the marker colour (median of the blob's
core), w = clip(<c - bg, fg - bg> / |fg - bg|^2, 0, 1). On an anti-aliased edge a pixel's
colour is the area-weighted mix of disc and background, so w is the covered fraction and the
weighted centroid is the area centroid to sub-pixel accuracy, where a binary mask would quantise
it to the pixel grid.

Given the camera's `background` (its view of the empty home, as the person detector learns it),
pixels already of the marker's colour there (a signpost's rings, a red cushion), grown by two
pixels, are not the marker, and a blob whose window reaches them is refused: a person half hiding
a signpost leaves a small convex red fragment that passes every disc test, and a disc touching a
static red region cannot be told apart from it.

Its covariance is the first-order propagation of the weights' noise: with c = sum w_i x_i / W,
dc/dw_i = (x_i - c) / W, so cov(c) = s_w^2 sum_i (x_i - c)(x_i - c)^T / W^2, s_w the standard
deviation of w estimated (median absolute deviation) on the background ring; a configured
`pixel_sigma` replaces it by sigma^2 I. A disc partly hidden by a straight edge (a door jamb, a
table's edge) still passes every shape test when a tenth of it is gone, and its centroid is then
a fifth of the blob's standard deviation off, ten times what the noise says. Such a blob is no
longer centrally symmetric: its skewness (`MarkerDetection.asymmetry`, in coordinates where the
blob's second moments are the identity) is 0.09 where a whole disc's image has none but its
pixels' noise, whose median falls with the area as about 12 area^-1.4 (measured on 1,483
detections of six calibration drives in the twin). A blob of 20 px or more whose asymmetry
exceeds `asymmetry_margin` times that is taken as partly hidden, and its covariance gets the
bias such a cut makes, (asymmetry sigma_blob)^2 I, sigma_blob the blob's larger standard
deviation: on 357 rendered detections (42 so taken) their mean NEES is 0.7, none above the
99.9 % gate. So taken: 92 % of the cut blobs 0.2 px or more off, and 2-4 % of whole ones,
which then only count for less. (Refusing them instead loses a tenth of a drive's detections
and its bedroom camera's tilt with them.) Below 20 px the skewness of whole discs reaches 2-3
by noise alone, and their propagated covariance is already large. The test is off by default
(`asymmetry_margin` 0): with it, a short calibration drive (16 stops, seed 2) converged to a
wrong network, which it does not without; `asymmetry` is reported either way.

Expected size. Given the camera (calibration and pose), the marker's height and its radius, a
blob is the marker only if it has the size and shape of the disc's image where it is: the disc
is placed where the blob's centre's ray meets the plane of the marker's height, its rim is
projected, and the ellipse of those second moments (a uniform ellipse's are half its rim's)
is compared with the blob's along its two axes and in aspect (`MarkerDetectorConfig.radius`);
where the disc would be under two pixels across it is not looked for. A red coat
stands upright and is many times the area of a 10 cm disc at the robot's height, a red sign
hangs far above it: both have a disc-like blob's shape in some views, never this size and
orientation.

People. A cv2 MOG2 background model (Zivkovic 2004) learns the empty room and keeps learning,
slowly, from the frames it detects in; shadows are dropped, a change of exposure is corrected
and a change of light relearnt (`PersonDetector`, docs/background-detector.md); each foreground
blob larger than `min_area` is a person. `PersonDetector.detect_bodies` (with the camera's
calibration) reports per blob the image of one well-defined body point, the foot of the body's
vertical axis, with a covariance that covers the body model's error: see `locate_body_axis` for
the geometry. `PersonDetector.detect` keeps the older blob report (bounding box and the blob's
lowest pixel), which is biased: the lowest pixel is the near edge of the body, about one body
radius from its centre towards the camera, so cameras on different sides disagree by a body
diameter. A learned person segmenter would feed `locate_body_axis` its mask instead.

Pixel coordinates have their origin at the centre of the top-left pixel (as the renderer).
"""

from __future__ import annotations

import colorsys
import math
from dataclasses import dataclass, field
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import ConvergenceError, InvalidInput
from core.geometry.camera import undistort_points
from core.geometry.rotations import wrap_angle
from core.localization._projection import project_plane
from core.localization.cameras import NetworkCamera

Array = NDArray[np.float64]
Image = NDArray[Any]

# A pixel whose colour lies further than this fraction of the marker/background contrast from
# the segment joining them is not a mix of the two.
_OFF_AXIS = 0.25


@dataclass(frozen=True)
class MarkerDetectorConfig:
    """How the coloured marker is segmented.

    colour: the marker's (r, g, b) 0..255 (its hue is what is matched); hue_tolerance: degrees
    of hue (0..180 OpenCV scale, i.e. 2 degrees per unit) either side; min_saturation,
    min_value: 0..255 floors; min_area, max_area: blob area bounds in pixels; min_solidity:
    blob area / convex hull area, rejecting blobs cut by an occluder into odd shapes;
    min_fill: blob area / the area inside its outer contour, rejecting blobs with a hole (a
    ring's image: a signpost's red rings seen from the ceiling fill 0.61-0.65 of their
    outline); min_ellipse_overlap: intersection over union of the blob with the ellipse of its
    second moments (a disc's image is an ellipse; one cut by an occluder's straight edge is not);
    border: blobs closer than this many pixels to the image edge are rejected (cut by the edge);
    pixel_sigma: when given (pixels), the centroid covariance is sigma^2 I instead of the one
    propagated from the image noise; min_sigma: a floor (pixels) on the propagated standard
    deviation, for the model errors the noise does not show (blur, distortion over the blob);
    asymmetry_margin: a blob of 20 px or more whose asymmetry exceeds this many times the
    median of whole discs of its area is taken as partly hidden and its covariance grown by
    the bias (module docstring; 0, the default, turns it off). With 3: 2-4 % of whole blobs,
    and 92 % of the cut blobs 0.2 px or more off (99 in six drives).
    radius: the marker disc's radius (m), when known; with the camera and the marker's height
    given to `detect_marker`, a blob must then have the size and shape of the disc's image at
    its place: along each axis of the predicted ellipse, its semi-axis b and the predicted a
    satisfy a / size_factor - size_margin <= b <= size_factor a + size_margin (pixels).
    size_margin: the blurred edge's pixels the hue threshold takes, which widen a blob by a
    fraction of a pixel whatever its size (b - a was 0.07-0.82 px on 203 of the twin's markers
    of 15-181 px, seen by its five cameras through their installed calibration). size_factor:
    what scales the image in a real home and not in the twin: the disc tilted with the robot
    on a rug or a threshold (4 degrees: x1.2 on the minor axis of a disc seen 19 degrees above
    the horizon, as a street camera sees the ground 25 m away), a placed camera's focal length
    and height errors (a few percent), a disc a tenth hidden (x0.9).
    The blob's aspect, once the same edge spread (0..size_margin) is taken off both axes, must
    also be the ellipse's within size_factor (a scale error scales both axes alike; only the
    disc's tilt changes the aspect). Where the disc's image would be under two pixels across,
    the marker is not looked for: a one-pixel red line has every shape a disc has there
    (module docstring: "Expected size").
    Measured on the twin's rendered markers (264 unhidden detections of three calibration
    drives against the true image ellipse centre): blobs of 60 px and more are 0.03-0.06 px
    off per axis where the propagated deviation is about 0.022 px (mean NEES 13 for the
    largest); with the floor at 0.04 px the mean NEES of all of them is 1.5 (expected 2).
    """

    colour: tuple[int, int, int] = (220, 20, 30)
    hue_tolerance: int = 10
    min_saturation: int = 100
    min_value: int = 60
    min_area: int = 12
    max_area: int = 20000
    min_solidity: float = 0.85
    min_fill: float = 0.9
    min_ellipse_overlap: float = 0.7
    border: int = 2
    pixel_sigma: float | None = None
    min_sigma: float = 0.04
    asymmetry_margin: float = 0.0
    radius: float | None = None
    size_factor: float = 1.25
    size_margin: float = 1.0

    def __post_init__(self) -> None:
        if len(self.colour) != 3 or not all(0 <= int(c) <= 255 for c in self.colour):
            raise InvalidInput(f"colour must be (r, g, b) in 0..255, got {self.colour}")
        if not 0 < self.hue_tolerance < 90:
            raise InvalidInput("hue_tolerance must lie in (0, 90) OpenCV hue units")
        if self.pixel_sigma is not None and not self.pixel_sigma > 0:
            raise InvalidInput("pixel_sigma must be > 0 pixels when given")
        if self.radius is not None and not (math.isfinite(self.radius) and self.radius > 0):
            raise InvalidInput("radius must be > 0 metres when given")
        if not (math.isfinite(self.size_factor) and self.size_factor >= 1):
            raise InvalidInput("size_factor must be >= 1")
        if not (math.isfinite(self.size_margin) and self.size_margin >= 0):
            raise InvalidInput("size_margin must be >= 0 pixels")
        if not (math.isfinite(self.asymmetry_margin) and self.asymmetry_margin >= 0):
            raise InvalidInput("asymmetry_margin must be >= 0 (0: off)")
        if not 0 < self.min_area <= self.max_area:
            raise InvalidInput("need 0 < min_area <= max_area")
        for name in ("min_solidity", "min_fill", "min_ellipse_overlap"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise InvalidInput(f"{name} must lie in [0, 1], got {getattr(self, name)}")


@dataclass(frozen=True)
class MarkerDetection:
    """One marker found in an image.

    pixel (2,): sub-pixel centre (distorted image pixels); cov (2, 2) px^2: its covariance;
    area: covered area in pixels (sum of the soft weights); contrast: |fg - bg| in grey levels
    (colour distance); weight_sigma: the per-pixel noise of the weights the covariance used;
    asymmetry: the blob's largest skewness (module docstring; 0 for a whole disc's image, but
    for its pixels' noise).
    """

    pixel: Array
    cov: Array = field(repr=False)
    area: float
    contrast: float
    weight_sigma: float
    asymmetry: float = 0.0

    @property
    def std(self) -> Array:
        """Standard deviations (2,) of (u, v), pixels."""
        return np.sqrt(np.diag(self.cov))


def _hue_mask(hsv: Image, cfg: MarkerDetectorConfig) -> NDArray[np.uint8]:
    r, g, b = (c / 255.0 for c in cfg.colour)
    hue = round(colorsys.rgb_to_hsv(r, g, b)[0] * 180.0) % 180
    d = np.abs(hsv[..., 0].astype(np.int16) - hue)
    d = np.minimum(d, 180 - d)  # hue is circular: red sits at both ends of the scale
    ok = (d <= cfg.hue_tolerance) & (hsv[..., 1] >= cfg.min_saturation)
    ok &= hsv[..., 2] >= cfg.min_value
    return ok.astype(np.uint8)


def _ellipse_overlap(blob: NDArray[np.uint8], x0: int, y0: int, bw: int, bh: int) -> float:
    """Return the IoU of a binary blob with the filled ellipse of the same second moments (a
    uniform ellipse of covariance S has semi-axes 2 sqrt(eig S))."""
    pad = 3
    h, w = blob.shape
    xa, ya = max(x0 - pad, 0), max(y0 - pad, 0)
    sub = blob[ya : min(y0 + bh + pad, h), xa : min(x0 + bw + pad, w)]
    m = cv2.moments(sub, True)
    if m["m00"] <= 0:
        return 0.0
    cx, cy = m["m10"] / m["m00"], m["m01"] / m["m00"]
    S = np.array([[m["mu20"], m["mu11"]], [m["mu11"], m["mu02"]]]) / m["m00"]
    ev, evec = np.linalg.eigh(S)
    if ev[0] <= 0:
        return 0.0
    angle = float(np.degrees(np.arctan2(evec[1, 1], evec[0, 1])))
    ell = np.zeros_like(sub)
    sh = 4  # fixed-point bits: sub-pixel centre and axes for cv2.ellipse
    cv2.ellipse(
        ell,
        (round(cx * 2**sh), round(cy * 2**sh)),
        (round(2 * np.sqrt(ev[1]) * 2**sh), round(2 * np.sqrt(ev[0]) * 2**sh)),
        angle,
        0,
        360,
        1,
        -1,
        cv2.LINE_8,
        sh,
    )
    inter = np.count_nonzero(sub & ell)
    union = np.count_nonzero(sub | ell)
    return inter / union if union else 0.0


def detect_marker(
    image: Image,
    config: MarkerDetectorConfig | None = None,
    *,
    background: Image | None = None,
    camera: NetworkCamera | None = None,
    height: float | None = None,
) -> MarkerDetection | None:
    """Return the marker's sub-pixel centre and covariance in a BGR image (H, W, 3), or None.

    The blobs of the marker's colour are tried from the largest to the smallest; the first that
    passes the area, border, fill, solidity and ellipse tests (`MarkerDetectorConfig`) is the
    marker (module docstring for the method). `background`: the same camera's view without the
    robot (BGR, same shape); what is of the marker's colour there is never the marker. With
    `camera` (the image's calibrated camera), `height` (the marker's height above the floor, m)
    and the config's `radius`, the blob must also have the size and shape of the disc's image
    where it is (`MarkerDetectorConfig.radius`). None when no blob passes. Raises InvalidInput
    for an image (or background) that is not (H, W, 3) uint8.
    """
    cfg = config or MarkerDetectorConfig()
    expect = None
    if camera is not None and height is not None and cfg.radius is not None:
        if not math.isfinite(height):
            raise InvalidInput(f"the marker's height must be finite, got {height}")
        expect = (camera, float(height), cfg.radius)
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise InvalidInput(f"image must be (H, W, 3) uint8 BGR, got {img.shape} {img.dtype}")
    h, w = img.shape[:2]
    mask = _hue_mask(cv2.cvtColor(img, cv2.COLOR_BGR2HSV), cfg)
    static = None
    if background is not None:
        static = static_marker_mask(background, cfg)
        if static.shape != mask.shape:
            raise InvalidInput(
                f"background is {static.shape[1]}x{static.shape[0]} px, the image {w}x{h}"
            )
        mask[static] = 0
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return None
    areas = stats[1:, cv2.CC_STAT_AREA]
    x0s, y0s = stats[1:, cv2.CC_STAT_LEFT], stats[1:, cv2.CC_STAT_TOP]
    x1s = x0s + stats[1:, cv2.CC_STAT_WIDTH]
    y1s = y0s + stats[1:, cv2.CC_STAT_HEIGHT]
    ok = (areas >= cfg.min_area) & (areas <= cfg.max_area)
    ok &= (x0s >= cfg.border) & (y0s >= cfg.border)
    ok &= (x1s <= w - cfg.border) & (y1s <= h - cfg.border)
    for i in np.flatnonzero(ok)[np.argsort(-areas[ok], kind="stable")]:
        found = _marker_at(img, labels, int(i) + 1, stats[int(i) + 1], cfg, static, expect)
        if found is not None:
            return found
    return None


def static_marker_mask(background: Image, config: MarkerDetectorConfig | None = None) -> Any:
    """Return the pixels (H, W) bool of a camera's `background` (BGR uint8, its view without
    the robot) that are of the marker's colour, grown by two pixels (anti-aliased edges, noise).
    Raises InvalidInput for a background that is not (H, W, 3) uint8."""
    cfg = config or MarkerDetectorConfig()
    bg = np.asarray(background)
    if bg.ndim != 3 or bg.shape[2] != 3 or bg.dtype != np.uint8:
        raise InvalidInput(f"background must be (H, W, 3) uint8 BGR, got {bg.shape} {bg.dtype}")
    m = _hue_mask(cv2.cvtColor(bg, cv2.COLOR_BGR2HSV), cfg)
    return cv2.dilate(m, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))).astype(bool)


def _disc_like(blob: NDArray[np.uint8], area: int, cfg: MarkerDetectorConfig) -> bool:
    """Return whether a blob (a window holding it with a margin, values 0/1) of `area` pixels
    has the shape of a disc's image: no hole, convex, elliptic."""
    contours, _ = cv2.findContours(blob, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    outer = max(contours, key=cv2.contourArea)
    filled = np.zeros_like(blob)
    cv2.drawContours(filled, [outer], -1, 1, -1)
    if area < cfg.min_fill * np.count_nonzero(filled):
        return False
    hull = cv2.contourArea(cv2.convexHull(outer))
    if hull <= 0 or area / hull < cfg.min_solidity:
        return False
    bx, by, bw, bh = cv2.boundingRect(outer)
    return _ellipse_overlap(blob, bx, by, bw, bh) >= cfg.min_ellipse_overlap


# The narrowest image of the marker's disc (px across its minor axis) it is looked for in: a
# disc seen narrower is a line of single pixels, which a red stripe or a tape's fragment makes
# alike; from two pixels across the hue mask shows its width, and the shape tests mean something.
_MIN_MARKER_WIDTH_PX = 2.0


def marker_ellipse(
    camera: NetworkCamera, pixel: ArrayLike, height: float, radius: float
) -> Array | None:
    """Return the second moments (2, 2) px^2 of the image of a horizontal disc of `radius` (m)
    at `height` (m) whose image is centred near `pixel` (2,) (distorted pixels), or None when
    the pixel's ray does not reach that height in front of the camera.

    The disc's centre is where the pixel's ray meets the plane Z = height; its rim, sampled at
    64 angles, is projected (distortion included). Over a disc's few pixels the projection is
    affine, and a uniform ellipse's second moments are half those of its rim taken uniformly
    in angle (a unit circle: 1/4 against 1/2 per axis)."""
    m = undistort_points(np.asarray(pixel, dtype=np.float64).reshape(1, 2), camera.K, camera.dist)
    ray = camera.R.T @ np.array([m[0, 0], m[0, 1], 1.0])
    c = camera.center
    if abs(ray[2]) < 1e-12:
        return None
    s = (height - c[2]) / ray[2]
    if not s > 0:
        return None
    centre = c + s * ray
    a = np.linspace(0.0, 2.0 * np.pi, 64, endpoint=False)
    rim = centre + radius * np.column_stack([np.cos(a), np.sin(a), np.zeros_like(a)])
    if np.any((rim @ camera.R.T + camera.t)[:, 2] <= 0):
        return None
    px = camera.project(rim)
    d = px - px.mean(axis=0)
    return (d.T @ d) / (2.0 * len(a))


def _expected_size(
    blob: NDArray[np.uint8],
    ox: int,
    oy: int,
    cfg: MarkerDetectorConfig,
    camera: NetworkCamera,
    height: float,
    radius: float,
) -> bool:
    """Return whether a blob (a window at (ox, oy) holding it, 0/1) has, along each axis of the
    ellipse a disc of `radius` at `height` makes where it is, a semi-axis within the config's
    `size_factor` and `size_margin` of the ellipse's (MarkerDetectorConfig.radius)."""
    mo = cv2.moments(blob, True)
    if mo["m00"] <= 0:
        return False
    centre = (mo["m10"] / mo["m00"] + ox, mo["m01"] / mo["m00"] + oy)
    S_pred = marker_ellipse(camera, centre, height, radius)
    if S_pred is None:
        return False
    # A binary blob's moments carry the pixel grid's 1/12 px^2 per axis.
    S_pred = S_pred + np.eye(2) / 12.0
    S_blob = np.array([[mo["mu20"], mo["mu11"]], [mo["mu11"], mo["mu02"]]]) / mo["m00"]
    ev, axes = np.linalg.eigh(S_pred)
    a = 2.0 * np.sqrt(ev)  # a uniform ellipse's semi-axes are twice its standard deviations
    if 2.0 * a[0] < _MIN_MARKER_WIDTH_PX:
        return False  # the disc would be a line there: no shape to test
    b = 2.0 * np.sqrt(np.maximum(np.einsum("ij,ik,kj->j", axes, S_blob, axes), 0.0))
    k, margin = cfg.size_factor, cfg.size_margin
    if not np.all((b >= a / k - margin) & (b <= k * a + margin)):
        return False
    # The shape: a scale error scales both axes alike and the edge's spread d (0..margin) is
    # one threshold on one blur, so (b_minor - d) / (b_major - d) is the predicted aspect
    # a_minor / a_major, but for the disc's tilt (size_factor).
    d = np.linspace(0.0, margin, 11)
    inner = b[1] - d
    ok = inner > 0
    aspect = np.maximum(b[0] - d[ok], 0.0) / inner[ok]
    want = a[0] / a[1]
    return bool(np.any((aspect >= want / k) & (aspect <= want * k)))


def _marker_at(
    img: Image,
    labels: NDArray[Any],
    k: int,
    stat: NDArray[Any],
    cfg: MarkerDetectorConfig,
    static: NDArray[np.bool_] | None = None,
    expect: tuple[NetworkCamera, float, float] | None = None,
) -> MarkerDetection | None:
    """Return the marker found at blob `k` of `labels` (its stats row `stat`), or None when
    the blob is not a disc's image, not that of a disc of the `expect`ed (camera, height,
    radius) where it is, its window reaches a `static` pixel (of the marker's colour without
    the robot) or its soft centroid is undefined."""
    h, w = img.shape[:2]
    x0, y0 = int(stat[cv2.CC_STAT_LEFT]), int(stat[cv2.CC_STAT_TOP])
    bw, bh = int(stat[cv2.CC_STAT_WIDTH]), int(stat[cv2.CC_STAT_HEIGHT])
    area = int(stat[cv2.CC_STAT_AREA])
    # A window holding the blob, its soft edge (4 px) and a background ring (4 px more).
    pad = 9
    xa, ya = max(x0 - pad, 0), max(y0 - pad, 0)
    xb, yb = min(x0 + bw + pad, w), min(y0 + bh + pad, h)
    core_m = (labels[ya:yb, xa:xb] == k).astype(np.uint8)
    if not _disc_like(core_m, area, cfg):
        return None
    if expect is not None and not _expected_size(core_m, xa, ya, cfg, *expect):
        return None
    win = img[ya:yb, xa:xb].astype(np.float64)
    k3 = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
    k5 = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
    inner = cv2.erode(core_m, k3).astype(bool)
    near = cv2.dilate(core_m, k5, iterations=2).astype(bool)
    far = cv2.dilate(core_m, k5, iterations=4).astype(bool)
    if static is not None and np.any(static[ya:yb, xa:xb] & near):
        return None
    ring = far & ~near
    if not np.any(ring):
        return None
    fg = np.median(win[inner if np.count_nonzero(inner) >= 3 else core_m.astype(bool)], axis=0)
    bg = np.median(win[ring], axis=0)
    axis = fg - bg
    contrast = float(np.linalg.norm(axis))
    if contrast < 1.0:
        return None
    rel = win - bg
    proj = rel @ axis / contrast**2
    # A mix of marker and its background lies on the segment bg-fg in colour space; anything
    # far off it (bright floor beside the robot, another object) is not part of the marker.
    off = np.linalg.norm(rel - proj[..., None] * axis, axis=-1)
    wts = np.where((off <= _OFF_AXIS * contrast) & near, np.clip(proj, 0.0, 1.0), 0.0)
    total = float(wts.sum())
    if total <= 0:
        return None
    ys, xs = np.mgrid[ya:yb, xa:xb].astype(np.float64)
    c = np.array([float((wts * xs).sum()), float((wts * ys).sum())]) / total
    skew, spread = _asymmetry(wts, xs - c[0], ys - c[1], total)
    if not math.isfinite(skew):
        return None  # weights on a line: no disc's image
    if cfg.pixel_sigma is not None:
        cov = cfg.pixel_sigma**2 * np.eye(2)
        s_w = float("nan")
    else:
        ring_w = (win[ring] - bg) @ axis / contrast**2
        s_w = float(1.4826 * np.median(np.abs(ring_w - np.median(ring_w))))
        dx, dy = (xs - c[0])[near], (ys - c[1])[near]
        cov = s_w**2 * np.array([[dx @ dx, dx @ dy], [dx @ dy, dy @ dy]]) / total**2
        cov = cov + cfg.min_sigma**2 * np.eye(2)
    if (
        cfg.asymmetry_margin > 0
        and total >= _MIN_SKEW_AREA
        and skew > cfg.asymmetry_margin * _whole_disc_asymmetry(total)
    ):
        # Partly hidden: the centroid is off by about the bias such a cut makes.
        cov = cov + (skew * spread) ** 2 * np.eye(2)
    return MarkerDetection(
        pixel=c, cov=cov, area=total, contrast=contrast, weight_sigma=s_w, asymmetry=skew
    )


_SKEW_DIRECTIONS = np.linspace(0.0, np.pi, 24, endpoint=False)
# Below this covered area (px) a blob's skewness is its pixels' noise (whole discs of 10 px
# reach 2-3), and its propagated covariance is already large.
_MIN_SKEW_AREA = 20.0


def _whole_disc_asymmetry(area: float) -> float:
    """Return the median asymmetry of a whole disc's image of `area` pixels (module docstring:
    its pixels' noise, measured)."""
    return 12.0 * max(area, 1.0) ** -1.4


def _asymmetry(w: Array, dx: Array, dy: Array, total: float) -> tuple[float, float]:
    """Return the largest skewness of the weights `w` over directions, in coordinates where
    their second moments are the identity (0 for the image of a whole disc, an ellipse being
    centrally symmetric; about 0.09 for a disc with a tenth of its area cut off by a straight
    edge, whose centroid is then a fifth of a standard deviation off its centre), and the
    weights' larger standard deviation (pixels). (inf, 0) when the moments are degenerate."""
    S = np.array([[(w * dx * dx).sum(), (w * dx * dy).sum()], [0.0, (w * dy * dy).sum()]])
    S[1, 0] = S[0, 1]
    S /= total
    ev, evec = np.linalg.eigh(S)
    if ev[0] <= 0:
        return float("inf"), 0.0
    # Whitened coordinates: z = diag(ev)^-1/2 evec^T d, of unit covariance.
    za = (evec[0, 0] * dx + evec[1, 0] * dy) / math.sqrt(ev[0])
    zb = (evec[0, 1] * dx + evec[1, 1] * dy) / math.sqrt(ev[1])
    m = w > 0
    za, zb, wm = za[m], zb[m], w[m]
    moments = (
        np.array(
            [
                (wm * za**3).sum(),
                (wm * za**2 * zb).sum(),
                (wm * za * zb**2).sum(),
                (wm * zb**3).sum(),
            ]
        )
        / total
    )
    c, s = np.cos(_SKEW_DIRECTIONS), np.sin(_SKEW_DIRECTIONS)
    g = (
        c**3 * moments[0]
        + 3 * c**2 * s * moments[1]
        + 3 * c * s**2 * moments[2]
        + s**3 * moments[3]
    )
    return float(np.abs(g).max()), math.sqrt(ev[1])


@dataclass(frozen=True)
class PersonDetection:
    """One person found by background subtraction (the blob, without the camera's geometry).

    foot_pixel (2,): the blob's lowest row (mean column there), distorted pixels: the body's
    near edge on the floor, not its centre (see the module docstring; `BodyDetection` is the
    unbiased report); cov (2, 2) px^2: sigma^2 I from the detector's `pixel_sigma`; bbox
    (x, y, w, h) pixels; area in pixels.
    """

    foot_pixel: Array
    cov: Array = field(repr=False)
    bbox: tuple[int, int, int, int]
    area: int


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


# MOG2's background ratio (its TB, OpenCV's default): a pixel's Gaussian is background once the
# weights of the Gaussians above it sum to less than this.
_MOG2_BACKGROUND_RATIO = 0.9
# The value MOG2 gives a pixel it takes for a shadow (darker, same chromaticity).
_MOG2_SHADOW = 127
# The exposure estimate reads every 4th pixel of every 4th row: 1/16 of a 640 x 480 view is
# 19,200 ratios, whose median is steady to 0.1 % between frames of one light.
_GAIN_STRIDE = 4
# Background grey levels outside this range say little of a gain (noise floor, saturation).
_GAIN_GREY = (16, 235)
# Frames between two readings of the live background for the exposure estimate: it changes
# over `still_frames` (hundreds), and reading it costs as much as a subtraction.
_GREY_REFRESH = 25


@dataclass(frozen=True)
class PersonBlobs:
    """What the background model made of one frame: `labels` (H, W) int32 connected
    components of the foreground (shadows left out), `blobs` the (label, (x, y, w, h), area)
    of those of at least `min_area` pixels, largest first, `foreground` the fraction of the
    frame that was foreground, `gain` the frame's exposure against the background's (1 when
    not estimated), and `relit` whether the frame was taken for a change of light (then no
    blob is reported and the model learns the frame again)."""

    labels: Image = field(repr=False)
    blobs: list[tuple[int, tuple[int, int, int, int], int]]
    foreground: float
    gain: float
    relit: bool


class PersonDetector:
    """People by background subtraction (cv2.createBackgroundSubtractorMOG2), one per camera.

    `learn(image)` feeds frames of the empty room (or any frames: MOG2 adapts); the foreground
    blobs larger than `min_area` pixels, opened and closed by a small kernel to remove speckle,
    are the people. `detect_bodies(image, camera)` reports each as its body axis's image
    (`locate_body_axis` with `body`, the body model); `detect(image)` as the blob and its lowest
    pixel, whose standard deviation is `pixel_sigma` (pixels).

    The model keeps learning from the frames it detects in (docs/background-detector.md):

    still_frames: frames after which something that stopped moving (a person asleep on a sofa,
    a moved chair) is background, and after which the ghost of something that stood there while
    the model learnt (a person standing at start-up who then walks off) is gone. Both are the
    time MOG2 needs to give a pixel's new colour the background's weight, so one setting sets
    both: the learning rate is alpha = -ln(0.9) / still_frames, when the older colour's weight
    (1 - alpha)^n falls below MOG2's background ratio 0.9. 300 frames is 60 s at 5 frames per
    second, 30 s at 10 and 10 s at 30; a walker covers a pixel for well under a second. None:
    no learning from live frames (the model is what `learn` taught it).
    shadows: MOG2's shadow detection (a pixel darker than the background by a factor in
    [0.5, 1], of its chromaticity), the shadows left out of the people.
    gain_tolerance: a frame's exposure against the background's is the median over the pixels
    of their grey ratio (people cover far less than half a view, so the median is the camera's
    gain); past this relative difference the frame is divided by it before the subtraction. An
    automatic exposure steps by 5-30 %; 2 % moves a mid-grey pixel by 2-3 grey levels, within
    the noise MOG2 accepts. None: no correction.
    relearn_fraction: a frame that is foreground over more than this fraction of its pixels
    (after the gain correction) saw the light change unevenly (a lamp switched on, the sun
    through a window): it reports no one, and the model learns again from it, as a new model
    does (rate 1 / (k + 1) on the k-th of `relearn_frames` frames, k from 1). People cover a
    few percent of a room camera's view and at most a fifth of a street camera's at its
    busiest; half a frame is no crowd that subtraction could part into people anyway. A walker
    covers a pixel for 2-3 frames at 5-10 frames per second (a body's 0.4 m at 0.8-1.4 m/s):
    after 50 frames their colour holds about a twentieth of that pixel's weight, under the
    tenth MOG2 leaves to background colours, so they are no part of the new background. With
    10 frames they were (a third), and the same walker coming back there was missed for
    minutes (tests/core/localization/test_background_model.py).
    """

    def __init__(
        self,
        *,
        history: int = 200,
        var_threshold: float = 25.0,
        min_area: int = 150,
        pixel_sigma: float = 2.0,
        body: BodyModel | None = None,
        still_frames: float | None = 300.0,
        shadows: bool = True,
        gain_tolerance: float | None = 0.02,
        relearn_fraction: float = 0.5,
        relearn_frames: int = 50,
    ) -> None:
        if min_area <= 0 or not pixel_sigma > 0:
            raise InvalidInput("min_area and pixel_sigma must be > 0")
        if still_frames is not None and not (math.isfinite(still_frames) and still_frames >= 1):
            raise InvalidInput(f"still_frames must be >= 1 frame or None, got {still_frames}")
        if gain_tolerance is not None and not (0 <= gain_tolerance < 1):
            raise InvalidInput(
                f"gain_tolerance must lie in [0, 1) or be None, got {gain_tolerance}"
            )
        if not 0 < relearn_fraction <= 1:
            raise InvalidInput(f"relearn_fraction must lie in (0, 1], got {relearn_fraction}")
        if relearn_frames < 1:
            raise InvalidInput(f"relearn_frames must be >= 1, got {relearn_frames}")
        self._mog = cv2.createBackgroundSubtractorMOG2(
            history=history, varThreshold=var_threshold, detectShadows=shadows
        )
        self._mog.setBackgroundRatio(_MOG2_BACKGROUND_RATIO)
        self.min_area = int(min_area)
        self.pixel_sigma = float(pixel_sigma)
        self.body = body or BodyModel()
        self.learning_rate = (
            0.0 if still_frames is None else -math.log(_MOG2_BACKGROUND_RATIO) / still_frames
        )
        self.gain_tolerance = gain_tolerance
        self.relearn_fraction = float(relearn_fraction)
        self.relearn_frames = int(relearn_frames)
        self._relearning = 0  # frames of a quick relearning still to go
        self._background: Image | None = None
        # The live model's background, grey, on the exposure grid, and frames since it was read.
        self._grey: NDArray[np.float32] | None = None
        self._grey_age = 0
        self._learnt = False

    def learn(self, image: Image) -> None:
        """Update the background model with a BGR frame (H, W, 3) of the empty room (at MOG2's
        own rate for a model learning: 1 / k on the k-th frame, then 1 / history)."""
        self._mog.apply(image, learningRate=-1)
        self._background = None
        self._grey = None
        self._learnt = True

    def background(self) -> Image | None:
        """Return the background `learn` taught (BGR, the model's most probable colour per
        pixel after the last `learn`), or None before anything is learnt. Live frames do not
        change it: it is the room as the installer showed it, without what came to rest since
        (the robot parked for minutes is background to the people, never to its marker)."""
        if self._background is None and self._learnt:
            self._background = self._mog.getBackgroundImage()
        return self._background

    def exposure(self, image: Image) -> float:
        """Return a BGR frame's exposure relative to the model's background: the median of the
        grey-level ratio frame / background over a grid of pixels (1/16 of them) whose
        background is neither dark nor saturated and whose frame is not saturated; 1 before
        anything is learnt or when fewer than 100 pixels qualify."""
        if not self._learnt:
            return 1.0
        if self._grey is None or self._grey_age >= _GREY_REFRESH:
            bg = self._mog.getBackgroundImage()
            grey = cv2.cvtColor(bg, cv2.COLOR_BGR2GRAY)[::_GAIN_STRIDE, ::_GAIN_STRIDE]
            self._grey = grey.astype(np.float32)
            self._grey_age = 0
        self._grey_age += 1
        ref = self._grey
        grid = np.ascontiguousarray(image[::_GAIN_STRIDE, ::_GAIN_STRIDE])
        cur = cv2.cvtColor(grid, cv2.COLOR_BGR2GRAY)
        ok = (ref >= _GAIN_GREY[0]) & (ref <= _GAIN_GREY[1]) & (cur < 255)
        if np.count_nonzero(ok) < 100:
            return 1.0
        return float(np.median(cur[ok].astype(np.float32) / ref[ok]))

    def segment(self, image: Image, *, learning_rate: float | None = None) -> PersonBlobs:
        """Return the foreground blobs of a BGR frame (H, W, 3), the model updated with it at
        `learning_rate` (None: the detector's own, from `still_frames`; 0: not updated).

        The frame is first brought to the background's exposure (`gain_tolerance`); a frame
        mostly foreground even so is taken for a change of light (`relearn_fraction`): it
        reports no blob and starts a quick relearning (class docstring)."""
        img = np.asarray(image)
        if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
            raise InvalidInput(f"image must be (H, W, 3) uint8 BGR, got {img.shape} {img.dtype}")
        rate = self.learning_rate if learning_rate is None else float(learning_rate)
        gain = 1.0
        if self.gain_tolerance is not None and self._learnt:
            gain = self.exposure(img)
            if abs(gain - 1.0) > self.gain_tolerance and gain > 0:
                img = cv2.convertScaleAbs(img, alpha=1.0 / gain)
        if self._relearning > 0:
            k = self.relearn_frames - self._relearning + 1  # 1, 2, ... relearn_frames
            rate = max(rate, 1.0 / (k + 1))
            self._relearning -= 1
        raw = self._mog.apply(img, learningRate=rate)
        fg: Image = (raw > _MOG2_SHADOW).astype(np.uint8)  # shadows (127) are no one
        share = float(np.count_nonzero(fg)) / fg.size
        if share > self.relearn_fraction:
            # The light changed: this frame becomes the model, and the next ones refine it.
            self._mog.apply(img, learningRate=1.0)
            self._grey = None
            self._relearning = self.relearn_frames
            empty = np.zeros(fg.shape, dtype=np.int32)
            return PersonBlobs(empty, [], share, gain, True)
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
        fg = cv2.morphologyEx(fg, cv2.MORPH_OPEN, kernel)
        fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, kernel, iterations=2)
        _, labels, stats, _ = cv2.connectedComponentsWithStats(fg, connectivity=8)
        areas = stats[1:, cv2.CC_STAT_AREA]
        keep = np.flatnonzero(areas >= self.min_area)
        keep = keep[np.argsort(-areas[keep], kind="stable")]
        blobs = [(int(k) + 1, _xywh(stats[int(k) + 1]), int(areas[k])) for k in keep]
        return PersonBlobs(labels, blobs, share, gain, False)

    def detect(self, image: Image, *, learning_rate: float | None = None) -> list[PersonDetection]:
        """Return the people (foreground blobs) in a BGR frame (H, W, 3), largest first; the
        model learns the frame at `learning_rate` (`segment`)."""
        seg = self.segment(image, learning_rate=learning_rate)
        labels, blobs = seg.labels, seg.blobs
        out = []
        for k, (x, y, bw, bh), area in blobs:
            bottom = y + bh - 1
            cols = np.flatnonzero(labels[bottom, x : x + bw] == k) + x
            foot = np.array([float(cols.mean()), float(bottom)])
            out.append(
                PersonDetection(
                    foot_pixel=foot,
                    cov=self.pixel_sigma**2 * np.eye(2),
                    bbox=(x, y, bw, bh),
                    area=area,
                )
            )
        return out

    def detect_bodies(
        self, image: Image, camera: NetworkCamera, *, learning_rate: float | None = None
    ) -> list[BodyDetection]:
        """Return the people in a BGR frame (H, W, 3) from `camera`, each as the image of their
        body axis at `body.axis_height` with its covariance (`locate_body_axis`), largest
        first. Blobs the body model cannot place (under the camera) are left out."""
        img = np.asarray(image)
        if camera.image_size is not None and img.shape[1::-1] != camera.image_size:
            raise InvalidInput(
                f"image is {img.shape[1]} x {img.shape[0]} but camera {camera.name!r} is "
                f"{camera.image_size[0]} x {camera.image_size[1]}: pass the camera that took it"
            )
        seg = self.segment(img, learning_rate=learning_rate)
        labels, blobs = seg.labels, seg.blobs
        out = []
        for k, (x, y, bw, bh), _ in blobs:
            det = locate_body_axis(
                labels[y : y + bh, x : x + bw] == k, camera, self.body, origin=(x, y)
            )
            if det is not None:
                out.append(det)
        return out


def _xywh(stat: NDArray[Any]) -> tuple[int, int, int, int]:
    return (int(stat[0]), int(stat[1]), int(stat[2]), int(stat[3]))
