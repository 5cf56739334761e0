"""The detections a ground estimator is given, checked once at the boundary: each camera's
pixels of each target, which camera saw which, and the pixel noise (module docstring of
core.localization.ground for the shapes and the errors)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_numeric
from core.errors import InvalidInput
from core.geometry.camera import undistort_points
from core.localization._checks import as_cameras
from core.localization._projection import inv2, normalized_to_pixel_jacobian
from core.localization.cameras import NetworkCamera

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Observations:
    """The detections of B targets by C cameras, checked, with the batch axis always present
    (`batched` says whether the caller gave one)."""

    cameras: tuple[NetworkCamera, ...]
    pixels: Array  # (C, B, 2), unseen entries replaced by the principal point
    visible: NDArray[np.bool_]  # (C, B)
    pixel_cov: Array | None  # (C, B, 2, 2) or None for isotropic
    pixel_sigma: float
    batched: bool

    @property
    def n_points(self) -> int:
        return int(self.pixels.shape[1])

    def chunks(self, size: int) -> list[Observations]:
        """Return the observations split along the batch into views of at most `size` targets."""
        if self.n_points <= size:
            return [self]
        return [
            Observations(
                self.cameras,
                self.pixels[:, i : i + size],
                self.visible[:, i : i + size],
                None if self.pixel_cov is None else self.pixel_cov[:, i : i + size],
                self.pixel_sigma,
                self.batched,
            )
            for i in range(0, self.n_points, size)
        ]

    def cov_of(self, k: int, idx: NDArray[np.intp] | slice) -> Array | float:
        """Pixel covariance of camera k's detections idx: (n, 2, 2), or sigma^2 as a scalar."""
        if self.pixel_cov is None:
            return self.pixel_sigma**2
        return self.pixel_cov[k, idx]


def parse_observations(
    cameras: Sequence[NetworkCamera] | NetworkCamera,
    pixels: ArrayLike,
    visible: ArrayLike | None,
    pixel_sigma: float,
    pixel_cov: ArrayLike | None,
) -> Observations:
    """Return the checked observations; raise InvalidInput for malformed arrays."""
    cams = as_cameras(cameras)
    n_cam = len(cams)
    px = as_numeric(pixels, "pixels", "(C, B, 2) or (C, 2)")
    if px.ndim == 2:
        batched = False
        px = px[:, None, :]
    else:
        batched = True
    if px.ndim != 3 or px.shape[0] != n_cam or px.shape[2] != 2:
        raise InvalidInput(
            f"pixels must have shape (C, B, 2) or (C, 2) with C = {n_cam} cameras, "
            f"got {np.shape(pixels)}"
        )
    n_pts = px.shape[1]
    if visible is None:
        vis = np.ones((n_cam, n_pts), dtype=bool)
    else:
        v = np.asarray(visible)
        if v.dtype != np.bool_:
            raise InvalidInput(f"visible must be a boolean array, got dtype {v.dtype}")
        want = (n_cam, n_pts) if batched else (n_cam,)
        if v.shape != want:
            raise InvalidInput(f"visible must have shape {want}, got {v.shape}")
        vis = v.reshape(n_cam, n_pts)
    if not np.all(np.isfinite(px[vis])):
        raise InvalidInput(
            "pixels contain NaN or infinite values for visible detections; mark those "
            "detections as not visible or remove them"
        )
    sigma = float(pixel_sigma)
    if not np.isfinite(sigma) or sigma <= 0:
        raise InvalidInput(f"pixel_sigma must be a positive number of pixels, got {pixel_sigma}")
    cov = None
    if pixel_cov is not None:
        try:
            cov = np.array(pixel_cov, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InvalidInput(f"pixel_cov must be numeric: {exc}") from None
        want_cov = (n_cam, n_pts, 2, 2) if batched else (n_cam, 2, 2)
        if cov.shape != want_cov:
            raise InvalidInput(f"pixel_cov must have shape {want_cov}, got {cov.shape}")
        cov = cov.reshape(n_cam, n_pts, 2, 2)
        c = cov[vis]
        if not np.all(np.isfinite(c)):
            raise InvalidInput("pixel_cov contains NaN or infinite values for visible detections")
        det = c[:, 0, 0] * c[:, 1, 1] - c[:, 0, 1] * c[:, 1, 0]
        asym = np.abs(c[:, 0, 1] - c[:, 1, 0]) > 1e-9 * np.sqrt(np.abs(c[:, 0, 0] * c[:, 1, 1]))
        if np.any(c[:, 0, 0] <= 0) or np.any(det <= 0) or np.any(asym):
            raise InvalidInput(
                "every visible detection's pixel_cov must be symmetric positive definite"
            )
        cov[~vis] = np.eye(2)
    # Unseen entries get a harmless finite value so that vectorised maths stays finite.
    for k, cam in enumerate(cams):
        px[k, ~vis[k]] = cam.K[:2, 2]
    return Observations(cams, px, vis, cov, sigma, batched)


def normalized(obs: Observations) -> tuple[Array, Array]:
    """Return ideal normalised coordinates (C, B, 2) and B_k^-1 = d m / d pixel (C, B, 2, 2)."""
    m = np.empty_like(obs.pixels)
    b_inv = np.empty((*obs.pixels.shape, 2))
    for k, cam in enumerate(obs.cameras):
        m[k] = undistort_points(obs.pixels[k], cam.K, cam.dist)
        b_inv[k] = inv2(normalized_to_pixel_jacobian(cam, m[k]))[0]
    return m, b_inv


def check_min_cameras(min_cameras: int, least: int) -> int:
    """Return min_cameras as an int; raise InvalidInput unless an integer >= least."""
    if int(min_cameras) != min_cameras or min_cameras < least:
        raise InvalidInput(f"min_cameras must be an integer >= {least}, got {min_cameras}")
    return int(min_cameras)
