"""The monocular ground estimator: one camera's back-projected ray meets the plane Z = h."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from core._validate import as_numeric
from core.errors import InvalidInput
from core.geometry.camera import undistort_points
from core.localization._checks import check_height
from core.localization._projection import inv2, project_plane, transposed
from core.localization.cameras import NetworkCamera
from core.localization.ground._batch import Raw, run_estimator
from core.localization.ground._estimate import FloorEstimate, PointStatus
from core.localization.ground._observations import Observations, parse_observations

# |cos| of the angle between a viewing ray and the plane Z = h below which the ray is parallel.
_PARALLEL_TOL = 1e-9


def locate_monocular(
    camera: NetworkCamera,
    pixels: ArrayLike,
    height: float = 0.0,
    *,
    pixel_sigma: float = 1.0,
    pixel_cov: ArrayLike | None = None,
) -> FloorEstimate:
    """Return the floor positions of pixels seen by one camera: the ray meets the plane Z = h.

    pixels: (B, 2) or (2,) distorted pixels; height: h, metres; pixel_sigma: isotropic pixel
    noise (px), or pixel_cov (B, 2, 2) / (2, 2) per detection (px^2).

    With m the ideal normalised coordinates of the pixel, the ray is X(l) = C + l d,
    d = R^T (m, 1), and l = (h - C_z) / d_z (H&Z eq. 6.14 for the back-projection). The
    covariance is the first-order propagation through the inverse of the projection restricted to
    the plane: cov = J^-1 S J^-T with J = d u / d(X, Y) at the estimate, S the pixel covariance.
    A ray parallel to the plane is DEGENERATE; one meeting the plane behind the camera (l <= 0) is
    BEHIND_CAMERA.
    """
    if not isinstance(camera, NetworkCamera):
        raise InvalidInput(f"camera must be a NetworkCamera, got {type(camera).__name__}")
    height = check_height(height)
    px = as_numeric(pixels, "pixels", "(B, 2) or (2,)")
    if px.ndim not in (1, 2):
        raise InvalidInput(f"pixels must have shape (B, 2) or (2,), got {px.shape}")
    cov = None if pixel_cov is None else np.asarray(pixel_cov, dtype=np.float64)[None]
    obs = parse_observations((camera,), px[None], None, pixel_sigma, cov)
    return run_estimator(obs, "monocular", height, 1, lambda o: _monocular_raw(o, height))


def _monocular_raw(obs: Observations, height: float) -> Raw:
    camera = obs.cameras[0]
    m = undistort_points(obs.pixels[0], camera.K, camera.dist)
    d = np.empty((obs.n_points, 3))
    d[:, :2] = m
    d[:, 2] = 1.0
    d = d @ camera.R  # R^T applied to each row
    c = camera.center
    dz = d[:, 2]
    status = np.zeros(obs.n_points, dtype=np.int8)
    parallel = np.abs(dz) <= _PARALLEL_TOL * np.linalg.norm(d, axis=1)
    status[parallel] = PointStatus.DEGENERATE
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = (height - c[2]) / np.where(parallel, 1.0, dz)
    status[~parallel & ~(lam > 0)] = PointStatus.BEHIND_CAMERA
    point = c + lam[:, None] * d
    point[:, 2] = height
    ok = np.flatnonzero(status == PointStatus.OK)
    J = project_plane(camera, point[ok, :2], height, jacobian=True).jacobian
    assert J is not None
    j_inv = inv2(J)[0]
    s = obs.cov_of(0, ok)
    point_cov = np.full((obs.n_points, 3, 3), np.nan)
    point_cov[ok] = 0.0
    if isinstance(s, float):
        point_cov[ok, :2, :2] = s * (j_inv @ transposed(j_inv))
    else:
        point_cov[ok, :2, :2] = j_inv @ s @ transposed(j_inv)
    return point, point_cov, status, np.ones(obs.n_points, dtype=np.int64), 0
