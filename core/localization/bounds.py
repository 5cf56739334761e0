"""The Cramer-Rao bound of a floor position seen by a camera network.

A target at (X, Y) on the plane Z = h, camera k measuring u_k = pi_k(X, Y, h) + e_k with
e_k ~ N(0, S_k) (S_k = sigma^2 I by default). The Fisher information of (X, Y) is

    F = sum_k J_k^T S_k^-1 J_k,        J_k = d pi_k / d(X, Y)                      (2 x 2)

(Kay, "Fundamentals of Statistical Signal Processing: Estimation Theory", eq. 3.31 for a
Gaussian model with parameter-independent covariance) and every unbiased estimator has
cov >= F^-1, the bound. With known h one camera already makes F invertible (the monocular fix);
it is singular only for a ray parallel to the plane.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_numeric
from core.errors import InvalidInput
from core.localization._checks import as_cameras, check_height
from core.localization._projection import inv2, project_plane, transposed
from core.localization.cameras import NetworkCamera

Array = NDArray[np.float64]


@dataclass(frozen=True)
class CramerRaoBound:
    """The bound per target, with the cameras it assumes.

    Shapes for B targets (without the batch axis, drop B): `cov` (B, 2, 2) m^2, the inverse
    Fisher information of (X, Y), NaN where no camera sees the target; `std` (B,) metres,
    sqrt(trace cov) (the smallest achievable RMS position error), inf where unseen; `visible`
    (C, B) which cameras were counted; `n_cameras` (B,).
    """

    cov: Array
    std: Array
    visible: NDArray[np.bool_] = field(repr=False)
    n_cameras: NDArray[np.int64] = field(repr=False)

    @property
    def root_mean_trace(self) -> float:
        """Return sqrt(mean over the seen targets of trace(cov)), metres.

        It is the RMSE an efficient estimator reaches over these targets, what a Monte Carlo
        RMSE over the same targets is compared with. NaN when no target is seen.
        """
        tr = np.atleast_1d(np.trace(self.cov, axis1=-2, axis2=-1))
        seen = np.isfinite(tr)
        return float(np.sqrt(np.mean(tr[seen]))) if np.any(seen) else float("nan")


def fisher_information(
    cameras: tuple[NetworkCamera, ...],
    xy: Array,
    height: float,
    visible: NDArray[np.bool_],
    pixel_sigma: float,
    pixel_cov: Array | None,
) -> Array:
    """Return F (B, 2, 2) = sum_k J_k^T S_k^-1 J_k over the cameras marked in visible (C, B)."""
    info = np.zeros((xy.shape[0], 2, 2))
    for k, cam in enumerate(cameras):
        J = project_plane(cam, xy, height, jacobian=True).jacobian
        assert J is not None
        if pixel_cov is None:
            f = (transposed(J) @ J) / pixel_sigma**2
        else:
            s_inv = inv2(pixel_cov[k])[0]
            f = transposed(J) @ s_inv @ J
        info += np.where(visible[k][:, None, None], f, 0.0)
    return info


def cramer_rao_bound(
    cameras: Sequence[NetworkCamera] | NetworkCamera,
    xy: ArrayLike,
    height: float = 0.0,
    *,
    pixel_sigma: float = 1.0,
    pixel_cov: ArrayLike | None = None,
    visible: ArrayLike | None = None,
) -> CramerRaoBound:
    """Return the Cramer-Rao bound of the floor positions xy (B, 2) or (2,) at Z = height.

    CRB = (sum_k J_k^T S_k^-1 J_k)^-1 (module docstring), J_k evaluated at the true point.
    pixel_sigma: isotropic pixel noise (px); pixel_cov (C, B, 2, 2) or (C, 2, 2) per detection
    instead. visible (C, B) or (C,): which cameras observe each target; by default those that
    image it (`NetworkCamera.in_view`: in front of the camera and inside the image).
    """
    cams = as_cameras(cameras)
    h = check_height(height)
    p = as_numeric(xy, "xy", "(B, 2) or (2,)")
    batched = p.ndim == 2
    p = p.reshape(-1, 2) if p.ndim in (1, 2) and p.shape[-1] == 2 else p
    if p.ndim != 2 or p.shape[1] != 2 or (not batched and p.shape[0] != 1):
        raise InvalidInput(f"xy must have shape (B, 2) or (2,), got {np.shape(xy)}")
    if not np.all(np.isfinite(p)):
        raise InvalidInput("xy contains NaN or infinite values")
    sigma = float(pixel_sigma)
    if not np.isfinite(sigma) or sigma <= 0:
        raise InvalidInput(f"pixel_sigma must be a positive number of pixels, got {pixel_sigma}")
    n_cam, n_pts = len(cams), p.shape[0]
    X = np.column_stack([p, np.full(n_pts, h)])
    if visible is None:
        vis = np.stack([c.in_view(X) for c in cams])
    else:
        v = np.asarray(visible)
        want = (n_cam, n_pts) if batched else (n_cam,)
        if v.dtype != np.bool_ or v.shape != want:
            raise InvalidInput(f"visible must be a boolean array of shape {want}, got {v.shape}")
        vis = v.reshape(n_cam, n_pts)
    cov_arr = None
    if pixel_cov is not None:
        cov_arr = np.asarray(pixel_cov, dtype=np.float64)
        want_cov = (n_cam, n_pts, 2, 2) if batched else (n_cam, 2, 2)
        if cov_arr.shape != want_cov or not np.all(np.isfinite(cov_arr)):
            raise InvalidInput(f"pixel_cov must be finite with shape {want_cov}")
        cov_arr = cov_arr.reshape(n_cam, n_pts, 2, 2)
        det = cov_arr[..., 0, 0] * cov_arr[..., 1, 1] - cov_arr[..., 0, 1] * cov_arr[..., 1, 0]
        if np.any((cov_arr[..., 0, 0] <= 0) | (det <= 0)):
            raise InvalidInput("every pixel_cov must be symmetric positive definite")
    info = fisher_information(cams, p, h, vis, sigma, cov_arr)
    cov, det = inv2(info)
    unseen = ~(det > 0)
    cov[unseen] = np.nan
    std = np.sqrt(np.trace(cov, axis1=1, axis2=2))
    std[unseen] = np.inf
    n = vis.sum(axis=0).astype(np.int64)
    if not batched:
        return CramerRaoBound(cov[0], std[0], vis[:, 0], n[0])
    return CramerRaoBound(cov, std, vis, n)
