"""Targets in camera images: the robot's coloured top marker and people (02 §2).

Robot marker. The image is segmented in HSV (hue within `hue_tolerance` of the marker's hue,
saturation and value above their floors), the largest connected blob is kept, and its centre is
the centroid of a *soft* membership weight over a window around the blob: each pixel's colour is
projected on the axis from the local background colour (median of a ring around the blob) to the
marker colour (median of the blob's core), w = clip(<c - bg, fg - bg> / |fg - bg|^2, 0, 1). On an
anti-aliased edge a pixel's colour is the area-weighted mix of disc and background, so w is the
covered fraction and the weighted centroid is the area centroid to sub-pixel accuracy, where a
binary mask would quantise it to the pixel grid.

Its covariance is the first-order propagation of the weights' noise: with c = sum w_i x_i / W,
dc/dw_i = (x_i - c) / W, so cov(c) = s_w^2 sum_i (x_i - c)(x_i - c)^T / W^2, s_w the standard
deviation of w estimated (median absolute deviation) on the background ring; a configured
`pixel_sigma` replaces it by sigma^2 I.

People. A cv2 MOG2 background model (Zivkovic 2004) learns the empty room; each foreground blob
larger than `min_area` is a person, whose foot point is the blob's lowest pixel row (the mean
column of that row), on the floor Z = 0. Person detection by a learned model would replace this
class without changing its result type.

Pixel coordinates have their origin at the centre of the top-left pixel (as the renderer).
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput

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
    min_ellipse_overlap: intersection over union of the blob with the ellipse of its second
    moments (a disc's image is an ellipse; one cut by an occluder's straight edge is not);
    border: blobs closer than this many pixels to the image edge are rejected (cut by the edge);
    pixel_sigma: when given (pixels), the centroid covariance is sigma^2 I instead of the one
    propagated from the image noise; min_sigma: a floor (pixels) on the propagated standard
    deviation, for the model errors the noise does not show (blur, distortion over the blob).
    """

    colour: tuple[int, int, int] = (220, 20, 30)
    hue_tolerance: int = 10
    min_saturation: int = 100
    min_value: int = 60
    min_area: int = 12
    max_area: int = 20000
    min_solidity: float = 0.85
    min_ellipse_overlap: float = 0.7
    border: int = 2
    pixel_sigma: float | None = None
    min_sigma: float = 0.02

    def __post_init__(self) -> None:
        if len(self.colour) != 3 or not all(0 <= int(c) <= 255 for c in self.colour):
            raise InvalidInput(f"colour must be (r, g, b) in 0..255, got {self.colour}")
        if not 0 < self.hue_tolerance < 90:
            raise InvalidInput("hue_tolerance must lie in (0, 90) OpenCV hue units")
        if self.pixel_sigma is not None and not self.pixel_sigma > 0:
            raise InvalidInput("pixel_sigma must be > 0 pixels when given")
        if not 0 < self.min_area <= self.max_area:
            raise InvalidInput("need 0 < min_area <= max_area")


@dataclass(frozen=True)
class MarkerDetection:
    """One marker found in an image.

    pixel (2,): sub-pixel centre (distorted image pixels); cov (2, 2) px^2: its covariance;
    area: covered area in pixels (sum of the soft weights); contrast: |fg - bg| in grey levels
    (colour distance); weight_sigma: the per-pixel noise of the weights the covariance used.
    """

    pixel: Array
    cov: Array = field(repr=False)
    area: float
    contrast: float
    weight_sigma: float

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
    image: Image, config: MarkerDetectorConfig | None = None
) -> MarkerDetection | None:
    """Return the marker's sub-pixel centre and covariance in a BGR image (H, W, 3), or None.

    None when no blob passes the colour, area, solidity and border tests (module docstring for
    the method). Raises InvalidInput for an image that is not (H, W, 3) uint8.
    """
    cfg = config or MarkerDetectorConfig()
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise InvalidInput(f"image must be (H, W, 3) uint8 BGR, got {img.shape} {img.dtype}")
    h, w = img.shape[:2]
    mask = _hue_mask(cv2.cvtColor(img, cv2.COLOR_BGR2HSV), cfg)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return None
    areas = stats[1:, cv2.CC_STAT_AREA]
    k = int(np.argmax(areas)) + 1
    area = int(stats[k, cv2.CC_STAT_AREA])
    if not cfg.min_area <= area <= cfg.max_area:
        return None
    x0, y0 = int(stats[k, cv2.CC_STAT_LEFT]), int(stats[k, cv2.CC_STAT_TOP])
    bw, bh = int(stats[k, cv2.CC_STAT_WIDTH]), int(stats[k, cv2.CC_STAT_HEIGHT])
    if x0 < cfg.border or y0 < cfg.border or x0 + bw > w - cfg.border or y0 + bh > h - cfg.border:
        return None
    blob = (labels == k).astype(np.uint8)
    contours, _ = cv2.findContours(blob, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    hull = cv2.contourArea(cv2.convexHull(max(contours, key=cv2.contourArea)))
    if hull <= 0 or area / hull < cfg.min_solidity:
        return None
    if _ellipse_overlap(blob, x0, y0, bw, bh) < cfg.min_ellipse_overlap:
        return None

    # A window holding the blob, its soft edge (4 px) and a background ring (4 px more).
    pad = 9
    xa, ya = max(x0 - pad, 0), max(y0 - pad, 0)
    xb, yb = min(x0 + bw + pad, w), min(y0 + bh + pad, h)
    win = img[ya:yb, xa:xb].astype(np.float64)
    core_m = blob[ya:yb, xa:xb]
    k3 = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
    k5 = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
    inner = cv2.erode(core_m, k3).astype(bool)
    near = cv2.dilate(core_m, k5, iterations=2).astype(bool)
    far = cv2.dilate(core_m, k5, iterations=4).astype(bool)
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
    if cfg.pixel_sigma is not None:
        cov = cfg.pixel_sigma**2 * np.eye(2)
        s_w = float("nan")
    else:
        ring_w = (win[ring] - bg) @ axis / contrast**2
        s_w = float(1.4826 * np.median(np.abs(ring_w - np.median(ring_w))))
        dx, dy = (xs - c[0])[near], (ys - c[1])[near]
        cov = s_w**2 * np.array([[dx @ dx, dx @ dy], [dx @ dy, dy @ dy]]) / total**2
        cov = cov + cfg.min_sigma**2 * np.eye(2)
    return MarkerDetection(pixel=c, cov=cov, area=total, contrast=contrast, weight_sigma=s_w)


@dataclass(frozen=True)
class PersonDetection:
    """One person found by background subtraction.

    foot_pixel (2,): the blob's lowest row (mean column there), distorted pixels, assumed on the
    floor Z = 0; cov (2, 2) px^2: sigma^2 I from the detector's `pixel_sigma`; bbox (x, y, w, h)
    pixels; area in pixels.
    """

    foot_pixel: Array
    cov: Array = field(repr=False)
    bbox: tuple[int, int, int, int]
    area: int


class PersonDetector:
    """People by background subtraction (cv2.createBackgroundSubtractorMOG2), one per camera.

    `learn(image)` feeds frames of the empty room (or any frames: MOG2 adapts); `detect(image)`
    returns the foreground blobs larger than `min_area` pixels, opened and closed by a small
    kernel to remove speckle. `pixel_sigma` (pixels) is the foot point's standard deviation,
    dominated by where the lowest row lies on the shoe, not by image noise.
    """

    def __init__(
        self,
        *,
        history: int = 200,
        var_threshold: float = 25.0,
        min_area: int = 150,
        pixel_sigma: float = 2.0,
    ) -> None:
        if min_area <= 0 or not pixel_sigma > 0:
            raise InvalidInput("min_area and pixel_sigma must be > 0")
        self._mog = cv2.createBackgroundSubtractorMOG2(
            history=history, varThreshold=var_threshold, detectShadows=False
        )
        self.min_area = int(min_area)
        self.pixel_sigma = float(pixel_sigma)

    def learn(self, image: Image) -> None:
        """Update the background model with a BGR frame (H, W, 3)."""
        self._mog.apply(image, learningRate=-1)

    def detect(self, image: Image, *, learning_rate: float = 0.0) -> list[PersonDetection]:
        """Return the people (foreground blobs) in a BGR frame (H, W, 3), largest first."""
        fg = self._mog.apply(image, learningRate=learning_rate)
        fg = (fg > 127).astype(np.uint8)
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
        fg = cv2.morphologyEx(fg, cv2.MORPH_OPEN, kernel)
        fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, kernel, iterations=2)
        n, labels, stats, _ = cv2.connectedComponentsWithStats(fg, connectivity=8)
        out = []
        for k in range(1, n):
            area = int(stats[k, cv2.CC_STAT_AREA])
            if area < self.min_area:
                continue
            x, y, bw, bh = (int(v) for v in stats[k, :4])
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
        out.sort(key=lambda d: -d.area)
        return out
