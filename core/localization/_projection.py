"""Projection of floor points and the small Jacobians every localisation estimator shares.

For a point (X, Y) on the plane Z = h seen by camera k (Xc = R X + t, pixel u = pi_k(Xc)), with
m = (x, y) its ideal normalised coordinates (undistorted, K^-1 removed):

    B_k = d u / d m = [[fx, s], [0, fy]] d(distortion) / d m                     (2 x 2)
    J_k = d u / d(X, Y) = B_k (d m / d Xc) R[:, :2]                              (2 x 2)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from core.geometry.camera import distortion_jacobian, distortion_model
from core.localization.cameras import NetworkCamera

Array = NDArray[np.float64]


@dataclass(frozen=True)
class PlaneProjection:
    """Pixels (B, 2), camera-frame depths (B,) and, if asked, J = d pixel / d(X, Y) (B, 2, 2)."""

    pixels: Array
    depth: Array
    jacobian: Array | None


def distort_to_pixels(
    camera: NetworkCamera, m: Array, *, jacobian: bool = False
) -> tuple[Array, Array | None]:
    """Return the pixels (B, 2) of ideal normalised coordinates m (B, 2) and B = d pixel / d m.

    The model of core.geometry.camera (`distortion_model`, `distortion_jacobian`: OpenCV's
    distortion of 5, 8, 12 or 14 coefficients), then K; only this 2 x 2 Jacobian, which costs
    about a tenth of project_points' full set (pose, intrinsics, distortion) on a batch.
    """
    K = camera.K
    fx, s, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    x = m[:, 0]
    y = m[:, 1]
    xd, yd, rad, r2 = distortion_model(x, y, camera.dist)
    pixels = np.empty_like(m)
    pixels[:, 0] = fx * xd + s * yd + cx
    pixels[:, 1] = fy * yd + cy
    if not jacobian:
        return pixels, None
    a11, a12, a21, a22 = distortion_jacobian(x, y, rad, r2, camera.dist)
    B = np.empty((m.shape[0], 2, 2))
    B[:, 0, 0] = fx * a11 + s * a21
    B[:, 0, 1] = fx * a12 + s * a22
    B[:, 1, 0] = fy * a21
    B[:, 1, 1] = fy * a22
    return pixels, B


def project_plane(
    camera: NetworkCamera, xy: Array, height: float, *, jacobian: bool = False
) -> PlaneProjection:
    """Return the projection of floor points xy (B, 2) at Z = height into `camera`.

    Xc = R[:, :2] (X, Y) + (R[:, 2] h + t), m = (Xc_x, Xc_y) / Xc_z, and
    d m_i / d(X, Y) = (R[i, :2] - m_i R[2, :2]) / Xc_z, so J = B (d m / d(X, Y)).
    """
    R = camera.R
    c = R[:, 2] * height + camera.t
    Xc = xy @ R[:, :2].T + c
    z = Xc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        iz = 1.0 / z
    m = Xc[:, :2] * iz[:, None]
    pixels, B = distort_to_pixels(camera, m, jacobian=jacobian)
    if B is None:
        return PlaneProjection(pixels=pixels, depth=z, jacobian=None)
    dm = (R[None, :2, :2] - m[:, :, None] * R[2, :2]) * iz[:, None, None]
    return PlaneProjection(pixels=pixels, depth=z, jacobian=B @ dm)


def normalized_to_pixel_jacobian(camera: NetworkCamera, m: Array) -> Array:
    """Return B = d pixel / d m (B, 2, 2) at ideal normalised coordinates m (B, 2)."""
    B = distort_to_pixels(camera, m, jacobian=True)[1]
    assert B is not None
    return B


def transposed(a: Array) -> Array:
    """Return the stacked matrices (..., n, m) transposed, as a contiguous array (..., m, n).

    numpy's batched matmul takes a slow path on a transposed view; a copy is 10x faster.
    """
    return np.ascontiguousarray(np.swapaxes(a, -1, -2))


def inv2(a: Array) -> tuple[Array, Array]:
    """Return (inverses (..., 2, 2), determinants (...)) of 2x2 matrices (..., 2, 2).

    Closed form; singular matrices give non-finite entries, which callers mask.
    """
    det = a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0]
    out = np.empty_like(a)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_det = 1.0 / det
        out[..., 0, 0] = a[..., 1, 1] * inv_det
        out[..., 0, 1] = -a[..., 0, 1] * inv_det
        out[..., 1, 0] = -a[..., 1, 0] * inv_det
        out[..., 1, 1] = a[..., 0, 0] * inv_det
    return out, det


def inv3(a: Array) -> tuple[Array, Array]:
    """Return (inverses (..., 3, 3), determinants (...)) of 3x3 matrices by the adjugate."""
    c00 = a[..., 1, 1] * a[..., 2, 2] - a[..., 1, 2] * a[..., 2, 1]
    c01 = a[..., 1, 2] * a[..., 2, 0] - a[..., 1, 0] * a[..., 2, 2]
    c02 = a[..., 1, 0] * a[..., 2, 1] - a[..., 1, 1] * a[..., 2, 0]
    det = a[..., 0, 0] * c00 + a[..., 0, 1] * c01 + a[..., 0, 2] * c02
    adj = np.empty_like(a)
    adj[..., 0, 0] = c00
    adj[..., 1, 0] = c01
    adj[..., 2, 0] = c02
    adj[..., 0, 1] = a[..., 0, 2] * a[..., 2, 1] - a[..., 0, 1] * a[..., 2, 2]
    adj[..., 1, 1] = a[..., 0, 0] * a[..., 2, 2] - a[..., 0, 2] * a[..., 2, 0]
    adj[..., 2, 1] = a[..., 0, 1] * a[..., 2, 0] - a[..., 0, 0] * a[..., 2, 1]
    adj[..., 0, 2] = a[..., 0, 1] * a[..., 1, 2] - a[..., 0, 2] * a[..., 1, 1]
    adj[..., 1, 2] = a[..., 0, 2] * a[..., 1, 0] - a[..., 0, 0] * a[..., 1, 2]
    adj[..., 2, 2] = a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        return adj / det[..., None, None], det


def whitening(cov: Array) -> Array:
    """Return W = L^-1 (..., 2, 2) with cov = L L^T (Cholesky), so that W e has unit covariance.

    Non-positive-definite inputs give non-finite entries; the caller validates covariances first.
    """
    a = cov[..., 0, 0]
    b = cov[..., 1, 0]
    c = cov[..., 1, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        l11 = np.sqrt(a)
        l21 = b / l11
        l22 = np.sqrt(c - l21 * l21)
        W = np.zeros_like(cov)
        W[..., 0, 0] = 1.0 / l11
        W[..., 1, 0] = -l21 / (l11 * l22)
        W[..., 1, 1] = 1.0 / l22
    return W
