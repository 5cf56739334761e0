"""The laser spot in an onboard image: bright, red, small; its sub-pixel centroid or "not seen".

A pixel belongs to the spot when it is both bright (red channel >= `min_red`) and red (red
exceeds the larger of green and blue by `min_redness` grey levels): a red laser saturates the
red channel while floor tiles, however bright, stay grey or tinted. The connected regions of
such pixels (8-connectivity, cv2.connectedComponentsWithStats) whose area lies within
[`min_area`, `max_area`] are candidates; the one with the largest summed redness is the spot,
and its centre is the redness-weighted centroid over a window around the region (first-order
image moments, sub-pixel: for a symmetric blob the weighted centroid is unbiased and its
error falls as the noise over the square root of the weights). No candidate, or two candidates
of comparable strength (a reflection), is "not seen" (None): a follower must never act on a
guess.

With a `background` (the same view with the laser off: the projector blinks it), the same rules
apply to the difference on - off (the red channel's rise, and its rise above the green and blue
channels' rises), which finds the spot on surfaces so bright that the laser saturates the red
channel without making the pixel much redder (a ceiling camera looking at a beige floor).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput

Array = NDArray[np.float64]


@dataclass(frozen=True)
class SpotDetectorConfig:
    """Thresholds of `detect_laser_spot` (grey levels 0..255, areas in pixels): `min_red`,
    `min_redness` on one image; `min_red_rise`, `min_redness_rise` on the difference with a
    laser-off background. `ambiguity`: a second candidate stronger than this fraction of the
    best makes the frame "not seen"."""

    min_red: int = 150
    min_redness: int = 60
    min_red_rise: int = 25
    min_redness_rise: int = 15
    min_area: int = 2
    max_area: int = 400
    ambiguity: float = 0.5


@dataclass(frozen=True)
class SpotDetection:
    """A detected spot: `pixel` (2,) sub-pixel centre (x right, y down, origin at the centre
    of the top-left pixel), `area` px, `strength` summed redness (grey levels x px)."""

    pixel: Array
    area: int
    strength: float


def _as_bgr(image: NDArray[np.uint8], name: str) -> NDArray[np.uint8]:
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise InvalidInput(
            f"{name} must be BGR uint8 of shape (H, W, 3), got {img.shape} {img.dtype}"
        )
    return img


def detect_laser_spot(
    image: NDArray[np.uint8],
    config: SpotDetectorConfig | None = None,
    *,
    background: NDArray[np.uint8] | None = None,
) -> SpotDetection | None:
    """Return the laser spot in a BGR image (H, W, 3) uint8, or None when it is not seen.

    `background`: the same view with the laser off, of the same shape (module docstring).
    """
    cfg = config or SpotDetectorConfig()
    img = _as_bgr(image, "image")
    b, g, r = (img[:, :, k].astype(np.int16) for k in range(3))
    if background is None:
        redness = r - np.maximum(g, b)
        mask = ((r >= cfg.min_red) & (redness >= cfg.min_redness)).astype(np.uint8)
    else:
        off = _as_bgr(background, "background")
        if off.shape != img.shape:
            raise InvalidInput(f"background {off.shape} and image {img.shape} differ in shape")
        b0, g0, r0 = (off[:, :, k].astype(np.int16) for k in range(3))
        dr = r - r0
        redness = dr - np.maximum(g - g0, b - b0)
        mask = ((dr >= cfg.min_red_rise) & (redness >= cfg.min_redness_rise)).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return None
    areas = stats[1:, cv2.CC_STAT_AREA]
    weight = np.clip(redness, 0, None).astype(np.float64)
    strength = np.bincount(labels.ravel(), weights=weight.ravel(), minlength=n)[1:]
    ok = (areas >= cfg.min_area) & (areas <= cfg.max_area)
    if not np.any(ok):
        return None
    strength = np.where(ok, strength, 0.0)
    order = np.argsort(strength)[::-1]
    best = int(order[0])
    if len(order) > 1 and strength[order[1]] > cfg.ambiguity * strength[best]:
        return None
    x0, y0 = stats[best + 1, cv2.CC_STAT_LEFT], stats[best + 1, cv2.CC_STAT_TOP]
    w, h = stats[best + 1, cv2.CC_STAT_WIDTH], stats[best + 1, cv2.CC_STAT_HEIGHT]
    # The window reaches two pixels past the region so the blob's thresholded skirt counts.
    xa, ya = max(x0 - 2, 0), max(y0 - 2, 0)
    xb, yb = min(x0 + w + 2, img.shape[1]), min(y0 + h + 2, img.shape[0])
    win = weight[ya:yb, xa:xb]
    # Subtract the window's background redness so the skirt's noise does not pull the centre.
    win = np.clip(win - np.median(win), 0, None)
    total = float(win.sum())
    if total <= 0:
        return None
    ys, xs = np.mgrid[ya:yb, xa:xb]
    centre = np.array([float((xs * win).sum()) / total, float((ys * win).sum()) / total])
    return SpotDetection(pixel=centre, area=int(areas[best]), strength=float(strength[best]))
