"""The image of the robot's marker disc: where a blob detector's area centroid falls with
respect to the image of the disc's centre, and the area the disc covers, through a camera's
perspective and lens distortion (the distorted image of an inscribed polygon of its rim)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.geometry.camera import project_points
from core.geometry.polygon import area_centroid, signed_area

Array = NDArray[np.float64]


def _disc_rim_image(
    X: Array, rvec: Array, t: Array, K: Array, dist: Array, radius: Array, n: int
) -> Array:
    """Return the distorted images (M, n, 2) of n points evenly spread on the rim of each
    horizontal disc of `radius` (M,) metres centred at X (M, 3)."""
    phi = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    rim = np.stack([np.cos(phi), np.sin(phi), np.zeros(n)], axis=1)
    pts = X[:, None, :] + radius[:, None, None] * rim[None]  # (M, n, 3)
    return project_points(pts.reshape(-1, 3), rvec, t, K, dist).points.reshape(len(X), n, 2)


def disc_centre_offset(
    X: Array, rvec: Array, t: Array, K: Array, dist: Array, radius: ArrayLike, n: int = 48
) -> Array:
    """Return the pixel offset (M, 2) of the area centroid of a horizontal disc's image from
    the image of its centre, for discs of `radius` metres (one value, or (M,)) centred at
    X (M, 3): what a blob detector's centroid measures (core.localization.detect).

    Two effects move it, both second order in the disc's size. Perspective: the disc's ideal
    image is an ellipse whose centre is not the image of the disc's centre (Hartley & Zisserman
    eq. 2.13; ~0.1 px for the twin's 5 cm marker at 3 m). Lens distortion: the image of that
    ellipse through a curved map is no ellipse, and its area centroid is not the distorted
    centre; with the default home's k1 = -0.28 it is c + k1 f x rho^2 off (x the normalised
    distance from the axis, rho the disc's radius in focal units): 0.2-0.6 px for the mast's
    8 cm disc at 1.5-2.5 m, off the axis. Both are in the area centroid of the distorted
    image of the rim, here an inscribed polygon of n points (an affine image of a regular
    polygon has its ellipse's centre; what the map adds beyond affine is O(n^-2) of the
    offset)."""
    r = np.broadcast_to(np.asarray(radius, dtype=np.float64), (len(X),))
    out = np.zeros((len(X), 2))
    on = r > 0
    if not np.any(on):
        return out
    uv = _disc_rim_image(X[on], rvec, t, K, dist, r[on], n)
    out[on] = area_centroid(uv) - project_points(X[on], rvec, t, K, dist).points
    return out


def disc_image_area(
    X: Array, rvec: Array, t: Array, K: Array, dist: Array, radius: ArrayLike, n: int = 48
) -> Array:
    """Return the image area (M,) in pixels of horizontal discs of `radius` (metres; one
    value, or (M,)) centred at X (M, 3), seen by the camera (rvec, t world-to-camera, K,
    dist): the area of the distorted images of n points on each rim (shoelace formula; the
    inscribed polygon's area, short of the ellipse's by about 2 pi^2 / (3 n^2), 0.3 % for
    n = 48)."""
    r = np.broadcast_to(np.asarray(radius, dtype=np.float64), (len(X),))
    area: Array = np.abs(signed_area(_disc_rim_image(X, rvec, t, K, dist, r, n)))
    return area
