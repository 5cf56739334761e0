"""The robot's coloured top marker in a camera image (02 §2).

The image is segmented in HSV (hue within `hue_tolerance` of the marker's hue,
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

Pixel coordinates have their origin at the centre of the top-left pixel (as the renderer).
"""

from __future__ import annotations

import colorsys
import math
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import InvalidInput
from core.geometry.camera import undistort_points
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
