"""Rotation matrices, rotation vectors and the nearest rotation. Batch dimensions come first."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


# [v]_x = v @ _SKEW9 reshaped: each entry one component of v, or its negation, exactly.
_SKEW9 = np.array(
    [
        [0.0, 0, 0, 0, 0, -1, 0, 1, 0],
        [0, 0, 1, 0, 0, 0, -1, 0, 0],
        [0, -1, 0, 1, 0, 0, 0, 0, 0],
    ]
)


def skew(v: ArrayLike) -> Array:
    """Return the cross-product matrices [v]_x, shape (..., 3, 3), of vectors v (..., 3)."""
    a = np.asarray(v, dtype=np.float64)
    # (one product where stacking the nine entries costs tens of numpy calls)
    return np.asarray((a @ _SKEW9).reshape(*a.shape[:-1], 3, 3), dtype=np.float64)


def rotvec_to_matrix(rvec: ArrayLike) -> Array:
    """Return rotation matrices (..., 3, 3) from rotation vectors (..., 3) (Rodrigues' formula).

    Uses the Taylor expansion of sin(t)/t and (1 - cos t)/t^2 near t = 0, so small angles keep
    full precision.
    """
    r = np.asarray(rvec, dtype=np.float64)
    theta2 = np.sum(r * r, axis=-1)
    theta = np.sqrt(theta2)
    small = theta2 < 1e-8
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
    k = skew(r)
    eye = np.broadcast_to(np.eye(3), k.shape)
    return eye + a[..., None, None] * k + b[..., None, None] * (k @ k)


def matrix_to_rotvec(R: ArrayLike) -> Array:
    """Return rotation vectors (..., 3) of rotation matrices (..., 3, 3), angle in [0, pi]."""
    m = np.asarray(R, dtype=np.float64)
    if m.ndim == 2:
        return matrix_to_rotvec(m[None])[0]
    cos_t = np.clip((np.trace(m, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos_t)
    w = np.stack(
        [m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]],
        -1,
    )
    sin_t = np.sin(theta)
    small = theta < 1e-6
    near_pi = theta > np.pi - 1e-4
    scale = np.where(small, 0.5 + theta**2 / 12.0, theta / (2.0 * np.where(small, 1.0, sin_t)))
    out = w * scale[..., None]
    if np.any(near_pi):
        # Near pi, w vanishes: take the axis from the symmetric part, R + I = 2 a a^T (+ O(eps)).
        idx = np.nonzero(near_pi)
        sym = (m[idx] + np.swapaxes(m[idx], -1, -2)) / 2.0 + np.eye(3)
        col = np.argmax(np.diagonal(sym, axis1=-2, axis2=-1), axis=-1)
        axis = np.take_along_axis(sym, col[..., None, None].repeat(3, -1), axis=-1)[..., 0]
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        sign = np.where(np.sum(axis * w[idx], axis=-1) < 0, -1.0, 1.0)
        out[idx] = axis * (theta[idx] * sign)[..., None]
    return out


def nearest_rotation(M: ArrayLike) -> Array:
    """Return the rotation nearest to M in the Frobenius norm, shape (..., 3, 3).

    R = U diag(1, 1, det(U V^T)) V^T from the SVD M = U S V^T (Zhang 2000, appendix C).
    """
    a = np.asarray(M, dtype=np.float64)
    u, _, vt = np.linalg.svd(a)
    d = np.sign(np.linalg.det(u @ vt))
    d = np.where(d == 0, 1.0, d)
    u = u.copy()
    u[..., :, 2] *= d[..., None]
    return u @ vt
