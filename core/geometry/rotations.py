"""Rotation matrices, rotation vectors, quaternions, the nearest rotation and angle wrapping.
Batch dimensions come first."""

from __future__ import annotations

import math
from typing import overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import InvalidInput

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


def quaternion_to_matrix(q_xyzw: ArrayLike) -> Array:
    """Return the rotations (..., 3, 3) of quaternions (..., 4) in (x, y, z, w) order,
    normalised first (Hamilton convention, R rotates body coordinates into the parent frame)."""
    q = np.asarray(q_xyzw, dtype=np.float64)
    if q.shape[-1:] != (4,):
        raise InvalidInput(f"quaternions must have shape (..., 4), got {q.shape}")
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_to_quaternion(R: ArrayLike) -> Array:
    """Return the unit quaternions (..., 4) in (x, y, z, w) order, w >= 0, of rotations
    (..., 3, 3).

    Shepperd's method (J. Guidance and Control 1(3), 1978): the largest of w^2, x^2, y^2, z^2 is
    taken from the trace or a diagonal element, so no division is by a small number and half
    turns keep full precision.
    """
    m = np.asarray(R, dtype=np.float64)
    if m.shape[-2:] != (3, 3):
        raise InvalidInput(f"rotations must have shape (..., 3, 3), got {m.shape}")
    a = m.reshape(-1, 3, 3)
    tr = np.trace(a, axis1=-2, axis2=-1)
    k = np.argmax(np.stack([a[:, 0, 0], a[:, 1, 1], a[:, 2, 2], tr], axis=1), axis=1)
    q = np.empty((len(a), 4))
    on = k == 3
    w = np.sqrt(1.0 + tr[on]) / 2.0
    b = a[on]
    v = np.stack([b[:, 2, 1] - b[:, 1, 2], b[:, 0, 2] - b[:, 2, 0], b[:, 1, 0] - b[:, 0, 1]], 1)
    q[on, :3] = v / (4 * w)[:, None]
    q[on, 3] = w
    for i in range(3):
        on = k == i
        j, l = (i + 1) % 3, (i + 2) % 3
        b = a[on]
        s = np.sqrt(1.0 + b[:, i, i] - b[:, j, j] - b[:, l, l]) * 2.0
        q[on, i] = s / 4.0
        q[on, j] = (b[:, j, i] + b[:, i, j]) / s
        q[on, l] = (b[:, l, i] + b[:, i, l]) / s
        q[on, 3] = (b[:, l, j] - b[:, j, l]) / s
    q = np.where(q[:, 3:] >= 0, q, -q)
    return q.reshape((*m.shape[:-2], 4))


@overload
def wrap_angle(a: float) -> float: ...
@overload
def wrap_angle(a: Array) -> Array: ...
def wrap_angle(a: float | Array) -> float | Array:
    """Return angles (radians, a float or any array) wrapped to [-pi, pi).

    (-pi, pi] is `-wrap_angle(-a)`.
    """
    if isinstance(a, float | int):
        return float((a + math.pi) % math.tau - math.pi)
    out: Array = (np.asarray(a, dtype=np.float64) + np.pi) % (2 * np.pi) - np.pi
    return out
