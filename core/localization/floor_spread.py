"""How far a floor point may have moved, in a camera's pixels.

A detection repeated after the fact (a source that reports changes, not frames, keeps saying
where it last saw a person) is uncertain by the distance the person may have walked since. That
spread is isotropic on the floor, sigma metres; in the image it is

    S = sigma^2 J J^T,    J = d pi(X, Y, 0) / d(X, Y)

at the floor point the pixel sees (core.localization._projection.project_plane, the same
Jacobian the tracker's update uses), so that the tracker, which maps the pixel covariance back
to the floor through the same J, sees exactly the floor spread sigma^2 I.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import ConvergenceError, InvalidInput
from core.localization._projection import project_plane
from core.localization.cameras import NetworkCamera
from core.localization.ground import locate_monocular

Array = NDArray[np.float64]


def floor_spread_cov(camera: NetworkCamera, pixels: ArrayLike, sigma_m: ArrayLike) -> Array:
    """Return S (N, 2, 2) px^2: the image of an isotropic floor spread sigma_m (N,) metres
    around the floor points (Z = 0) seen at the distorted pixels (N, 2). A pixel whose ray
    misses the floor (above the horizon), or where the lens model cannot be inverted, gets an
    infinite spread."""
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    sigma = np.broadcast_to(np.asarray(sigma_m, dtype=np.float64), (px.shape[0],))
    if not np.all(np.isfinite(sigma)) or np.any(sigma < 0):
        raise InvalidInput("sigma_m must be finite and >= 0 metres")
    xy = _floor_points(camera, px)
    ok = np.all(np.isfinite(xy), axis=1)
    out = np.full((px.shape[0], 2, 2), np.inf)
    if ok.any():
        J = project_plane(camera, xy[ok], 0.0, jacobian=True).jacobian
        assert J is not None
        out[ok] = sigma[ok, None, None] ** 2 * (J @ np.swapaxes(J, 1, 2))
    return out


def _floor_points(camera: NetworkCamera, px: Array) -> Array:
    """Return the floor points (N, 2) the pixels see, NaN where the ray misses the floor or the
    lens model cannot be inverted at the pixel (each pixel alone then, so one such pixel does
    not cost the others theirs)."""
    try:
        return locate_monocular(camera, px, 0.0).point[..., :2].reshape(-1, 2)
    except ConvergenceError:
        out = np.full((px.shape[0], 2), np.nan)
        for i in range(px.shape[0]):
            try:
                out[i] = locate_monocular(camera, px[i : i + 1], 0.0).point[..., :2].reshape(2)
            except ConvergenceError:
                continue
        return out
