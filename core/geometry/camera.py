"""The pinhole camera with OpenCV's lens distortion: projection, analytic Jacobians, undistortion.

Model (OpenCV calib3d, "Camera Calibration and 3D Reconstruction"; Zhang 2000, eq. 1 and 11-12
for the radial part). A point X (world, metres or any length unit) goes to the camera frame by
the pose (rotation vector rvec, translation t), Xc = R(rvec) X + t, then

    x = Xc / Zc,  y = Yc / Zc,  r^2 = x^2 + y^2,  rad = 1 + k1 r^2 + k2 r^4 + k3 r^6
    x_d = x rad + 2 p1 x y + p2 (r^2 + 2 x^2)
    y_d = y rad + p1 (r^2 + 2 y^2) + 2 p2 x y
    u = fx x_d + s y_d + cx,   v = fy y_d + cy                      (pixels)

so that K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]] acts on the *distorted* normalised coordinates,
exactly as in cv2.projectPoints (which has s = 0) and as in Zhang's model with
alpha = fx, gamma = s, beta = fy.

OpenCV's longer models are supported too (8, 12 or 14 coefficients: k1 k2 p1 p2 k3 k4 k5 k6
s1 s2 s3 s4 tau_x tau_y): the rational radial factor, thin prism terms and the tilted sensor,

    rad = (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)
    x_d' = x rad + 2 p1 x y + p2 (r^2 + 2 x^2) + s1 r^2 + s2 r^4
    y_d' = y rad + p1 (r^2 + 2 y^2) + 2 p2 x y + s3 r^2 + s4 r^4
    (x_d, y_d) = the projection of M(tau_x, tau_y) (x_d', y_d', 1)

with M OpenCV's tilt projection matrix (computeTiltProjectionMatrix). A model of at most five
coefficients is computed as five (the common fast path), a longer one as fourteen.

Parameter orders used throughout: intrinsics (fx, fy, cx, cy, s); distortion (k1, k2, p1, p2,
k3[, k4, k5, k6, s1, s2, s3, s4, tau_x, tau_y]) as OpenCV; pose (rvec (3), t (3)).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import ConvergenceError, InvalidInput
from core.geometry.rotations import matrix_to_rotvec, rotvec_to_matrix

Array = NDArray[np.float64]

INTRINSIC_NAMES: tuple[str, ...] = ("fx", "fy", "cx", "cy", "skew")
DISTORTION_NAMES: tuple[str, ...] = ("k1", "k2", "p1", "p2", "k3")
FULL_DISTORTION_NAMES: tuple[str, ...] = (
    *DISTORTION_NAMES,
    *("k4", "k5", "k6", "s1", "s2", "s3", "s4", "tau_x", "tau_y"),
)
# Coefficient counts OpenCV defines past five: rational (8), thin prism (12), tilted (14).
LONG_DISTORTION_SIZES = (8, 12, 14)


def intrinsics_to_matrix(intrinsics: ArrayLike) -> Array:
    """Return K (..., 3, 3) from intrinsics (..., 5) in the order (fx, fy, cx, cy, skew)."""
    p = np.asarray(intrinsics, dtype=np.float64)
    K = np.zeros((*p.shape[:-1], 3, 3))
    K[..., 0, 0] = p[..., 0]
    K[..., 1, 1] = p[..., 1]
    K[..., 0, 2] = p[..., 2]
    K[..., 1, 2] = p[..., 3]
    K[..., 0, 1] = p[..., 4]
    K[..., 2, 2] = 1.0
    return K


def matrix_to_intrinsics(K: ArrayLike) -> Array:
    """Return intrinsics (..., 5) = (fx, fy, cx, cy, skew) of upper-triangular K (..., 3, 3)."""
    k = np.asarray(K, dtype=np.float64)
    k = k / k[..., 2:3, 2:3]
    return np.stack([k[..., 0, 0], k[..., 1, 1], k[..., 0, 2], k[..., 1, 2], k[..., 0, 1]], -1)


def as_distortion(dist: ArrayLike | None) -> Array:
    """Return distortion coefficients as (k1, k2, p1, p2, k3), shape (5,), zero-padded."""
    if dist is None:
        return np.zeros(5)
    d = np.asarray(dist, dtype=np.float64).ravel()
    if d.size > 5 or not np.all(np.isfinite(d)):
        raise InvalidInput(
            f"dist must hold at most 5 finite coefficients (k1, k2, p1, p2, k3), got {d.size}"
        )
    return np.concatenate([d, np.zeros(5 - d.size)])


def as_distortion_model(dist: ArrayLike | None) -> Array:
    """Return distortion coefficients as the model computes them: (5,) when at most five are
    given, (14,) for OpenCV's 8, 12 or 14 (zero-padded). Raise InvalidInput for another count or
    a non-finite coefficient."""
    if dist is None:
        return np.zeros(5)
    d = np.asarray(dist, dtype=np.float64).ravel()
    if not np.all(np.isfinite(d)) or (d.size > 5 and d.size not in LONG_DISTORTION_SIZES):
        raise InvalidInput(
            "dist must hold 0 to 5, 8, 12 or 14 finite coefficients (OpenCV's k1, k2, p1, p2, "
            f"k3, k4, k5, k6, s1, s2, s3, s4, tau_x, tau_y), got {d.size}"
        )
    n = 5 if d.size <= 5 else 14
    return np.concatenate([d, np.zeros(n - d.size)])


def tilt_matrix(tau_x: float, tau_y: float) -> tuple[Array, Array, Array]:
    """Return OpenCV's tilt projection matrix M (3, 3) of a sensor tilted by tau_x, tau_y
    (radians; calib3d's computeTiltProjectionMatrix) and its derivatives dM/dtau_x, dM/dtau_y."""
    cx, sx, cy, sy = np.cos(tau_x), np.sin(tau_x), np.cos(tau_y), np.sin(tau_y)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, sx], [0.0, -sx, cx]])
    ry = np.array([[cy, 0.0, -sy], [0.0, 1.0, 0.0], [sy, 0.0, cy]])
    drx = np.array([[0.0, 0.0, 0.0], [0.0, -sx, cx], [0.0, -cx, -sx]])
    dry = np.array([[-sy, 0.0, -cy], [0.0, 0.0, 0.0], [cy, 0.0, -sy]])

    def proj_z(r: Array, one: float) -> Array:
        return np.array([[r[2, 2], 0.0, -r[0, 2]], [0.0, r[2, 2], -r[1, 2]], [0.0, 0.0, one]])

    rxy = ry @ rx
    M = proj_z(rxy, 1.0) @ rxy
    dM = []
    for d in (ry @ drx, dry @ rx):
        dM.append(proj_z(d, 0.0) @ rxy + proj_z(rxy, 1.0) @ d)
    return M, dM[0], dM[1]


def left_jacobian_so3(rvec: ArrayLike) -> Array:
    """Return the left Jacobian of SO(3), shape (..., 3, 3), at rotation vectors (..., 3).

    J_l(v) = I + (1 - cos t)/t^2 [v]x + (t - sin t)/t^3 [v]x^2, t = |v|, so that
    R(v + dv) = exp([J_l dv]x) R(v) to first order, hence d(R(v) X)/dv = -[R X]x J_l(v)
    (Barfoot, "State Estimation for Robotics", eq. 7.77 and 7.86). Taylor series near t = 0.
    """
    v = np.asarray(rvec, dtype=np.float64)
    t2 = np.sum(v * v, axis=-1)
    t = np.sqrt(t2)
    small = t2 < 1e-6
    safe = np.where(small, 1.0, t)
    a = np.where(small, 0.5 - t2 / 24.0 + t2 * t2 / 720.0, (1.0 - np.cos(safe)) / (safe * safe))
    b = np.where(small, 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0, (safe - np.sin(safe)) / safe**3)
    z = np.zeros(v.shape[:-1])
    k = np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], z, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        -2,
    )
    return np.eye(3) + a[..., None, None] * k + b[..., None, None] * (k @ k)


def distortion_model(x: Array, y: Array, dist: ArrayLike) -> tuple[Array, Array, Array, Array]:
    """Return (x_d, y_d, rad, r^2) for ideal normalised coordinates x, y (any shape) and the
    coefficients (k1, k2, p1, p2, k3), or OpenCV's fourteen (`as_distortion_model`): the one
    implementation of the model of the module docstring, shared by projection, undistortion
    and the localisation estimators. rad is the radial factor (rational for fourteen)."""
    d = np.asarray(dist, dtype=np.float64).ravel()
    if d.size == 14:
        xd, yd, rad, r2, _ = _long_model(x, y, d)
        return xd, yd, rad, r2
    k1, k2, p1, p2, k3 = (float(v) for v in d.reshape(5))
    xx, yy, xy2 = x * x, y * y, 2.0 * x * y
    r2 = xx + yy
    rad = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * rad + p1 * xy2 + p2 * (r2 + 2.0 * xx)
    yd = y * rad + p1 * (r2 + 2.0 * yy) + p2 * xy2
    return xd, yd, rad, r2


@dataclass(frozen=True)
class _LongTerms:
    """What the 14-coefficient model's Jacobians reuse: the numerator and denominator of rad,
    the distorted point before the tilt (x_d', y_d'), and the tilt's homogeneous scale w."""

    den: Array
    xd0: Array
    yd0: Array
    w: Array | None


def _long_model(x: Array, y: Array, d: Array) -> tuple[Array, Array, Array, Array, _LongTerms]:
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tx, ty = (float(v) for v in d)
    xx, yy, xy2 = x * x, y * y, 2.0 * x * y
    r2 = xx + yy
    r4 = r2 * r2
    num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    rad = num / den
    xd0 = x * rad + p1 * xy2 + p2 * (r2 + 2.0 * xx) + s1 * r2 + s2 * r4
    yd0 = y * rad + p1 * (r2 + 2.0 * yy) + p2 * xy2 + s3 * r2 + s4 * r4
    if tx == 0.0 and ty == 0.0:
        return xd0, yd0, rad, r2, _LongTerms(den, xd0, yd0, None)
    M = tilt_matrix(tx, ty)[0]
    w = M[2, 0] * xd0 + M[2, 1] * yd0 + M[2, 2]
    xd = (M[0, 0] * xd0 + M[0, 1] * yd0 + M[0, 2]) / w
    yd = (M[1, 0] * xd0 + M[1, 1] * yd0 + M[1, 2]) / w
    return xd, yd, rad, r2, _LongTerms(den, xd0, yd0, w)


def distortion_jacobian(
    x: Array, y: Array, rad: Array, r2: Array, dist: ArrayLike
) -> tuple[Array, Array, Array, Array]:
    """Return (a11, a12, a21, a22): d(x_d, y_d) / d(x, y) = [[a11, a12], [a21, a22]] at x, y,
    with rad and r^2 from `distortion_model` (symmetric for at most five coefficients, where
    a21 is a12; thin prism and tilt break the symmetry)."""
    d = np.asarray(dist, dtype=np.float64).ravel()
    if d.size != 14:
        k1, k2, p1, p2, k3 = (float(v) for v in d.reshape(5))
        drad = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d rad / d r^2
        a11 = rad + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x
        a12 = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y
        a22 = rad + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x
        return a11, a12, a12, a22
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tx, ty = (float(v) for v in d)
    xd, yd, rad, r2, terms = _long_model(x, y, d)
    dnum = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
    dden = k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2)
    drad = (dnum - rad * dden) / terms.den
    px = 2.0 * (s1 + 2.0 * s2 * r2)  # d(s1 r^2 + s2 r^4) / d(x or y), over x or y
    py = 2.0 * (s3 + 2.0 * s4 * r2)
    common = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y
    a11 = rad + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x + x * px
    a12 = common + y * px
    a21 = common + x * py
    a22 = rad + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x + y * py
    if terms.w is None:
        return a11, a12, a21, a22
    t11, t12, t21, t22 = _tilt_jacobian(xd, yd, terms.w, tilt_matrix(tx, ty)[0])
    return (
        t11 * a11 + t12 * a21,
        t11 * a12 + t12 * a22,
        t21 * a11 + t22 * a21,
        t21 * a12 + t22 * a22,
    )


def _tilt_jacobian(xd: Array, yd: Array, w: Array, M: Array) -> tuple[Array, Array, Array, Array]:
    # d(x_d, y_d) / d(x_d', y_d') of the projective map (x_d, y_d) = (M (x_d', y_d', 1))[:2] / w.
    return (
        (M[0, 0] - xd * M[2, 0]) / w,
        (M[0, 1] - xd * M[2, 1]) / w,
        (M[1, 0] - yd * M[2, 0]) / w,
        (M[1, 1] - yd * M[2, 1]) / w,
    )


def distortion_coefficient_jacobian(x: Array, y: Array, dist: ArrayLike) -> Array:
    """Return d(x_d, y_d) / d(coefficients), shape (..., 2, 14), of the 14-coefficient model
    (`as_distortion_model`) at ideal normalised coordinates x, y (...)."""
    d = np.asarray(dist, dtype=np.float64).ravel()
    if d.size != 14:
        raise InvalidInput(f"the coefficient Jacobian is of the 14-coefficient model, got {d.size}")
    xd, yd, rad, r2, terms = _long_model(x, y, d)
    r4 = r2 * r2
    r6 = r4 * r2
    zero = np.zeros_like(x)
    # Before the tilt: d x_d' and d y_d' by each coefficient, in FULL_DISTORTION_NAMES order.
    inv = 1.0 / terms.den
    k123 = [r2 * inv, r4 * inv, r6 * inv]  # d rad / d(k1, k2, k3)
    k456 = [-rad * r2 * inv, -rad * r4 * inv, -rad * r6 * inv]  # d rad / d(k4, k5, k6)
    xy2 = 2.0 * x * y
    dx0 = [x * k123[0], x * k123[1], xy2, r2 + 2.0 * x * x, x * k123[2]]
    dy0 = [y * k123[0], y * k123[1], r2 + 2.0 * y * y, xy2, y * k123[2]]
    dx0 += [x * f for f in k456] + [r2, r4, zero, zero]
    dy0 += [y * f for f in k456] + [zero, zero, r2, r4]
    out = np.empty((*np.shape(x), 2, 14))
    if terms.w is None:
        out[..., 0, :12] = np.stack(dx0, -1)
        out[..., 1, :12] = np.stack(dy0, -1)
        out[..., :, 12:] = 0.0
        return out
    M, dMx, dMy = tilt_matrix(d[12], d[13])
    t11, t12, t21, t22 = _tilt_jacobian(xd, yd, terms.w, M)
    DX0, DY0 = np.stack(dx0, -1), np.stack(dy0, -1)
    out[..., 0, :12] = t11[..., None] * DX0 + t12[..., None] * DY0
    out[..., 1, :12] = t21[..., None] * DX0 + t22[..., None] * DY0
    for k, dM in ((12, dMx), (13, dMy)):
        v0 = dM[0, 0] * terms.xd0 + dM[0, 1] * terms.yd0 + dM[0, 2]
        v1 = dM[1, 0] * terms.xd0 + dM[1, 1] * terms.yd0 + dM[1, 2]
        v2 = dM[2, 0] * terms.xd0 + dM[2, 1] * terms.yd0 + dM[2, 2]
        out[..., 0, k] = (v0 - xd * v2) / terms.w
        out[..., 1, k] = (v1 - yd * v2) / terms.w
    return out


def distort_normalized(xy: ArrayLike, dist: ArrayLike | None) -> Array:
    """Return distorted normalised coordinates (..., 2) of ideal ones xy (..., 2).

    OpenCV's model of 0 to 5, 8, 12 or 14 coefficients, see the module docstring.
    """
    p = np.asarray(xy, dtype=np.float64)
    xd, yd, _, _ = distortion_model(p[..., 0], p[..., 1], as_distortion_model(dist))
    return np.stack([xd, yd], -1)


@dataclass(frozen=True)
class Projection:
    """Projected pixels and, if requested, their analytic Jacobians.

    Shapes for a batch (...,) of N points: `points` (..., N, 2) pixels; `d_intrinsics`
    (..., N, 2, 5) wrt (fx, fy, cx, cy, skew); `d_distortion` (..., N, 2, 5) wrt
    (k1, k2, p1, p2, k3), or (..., N, 2, 14) wrt FULL_DISTORTION_NAMES for a camera of 8, 12 or
    14 coefficients; `d_pose` (..., N, 2, 6) wrt (rvec, t); `depth` (..., N) the camera-frame
    Z of every point (negative: behind the camera).
    """

    points: Array
    depth: Array
    d_intrinsics: Array | None = field(default=None, repr=False)
    d_distortion: Array | None = field(default=None, repr=False)
    d_pose: Array | None = field(default=None, repr=False)


def project_points(
    object_points: ArrayLike,
    rvec: ArrayLike,
    tvec: ArrayLike,
    K: ArrayLike,
    dist: ArrayLike | None = None,
    *,
    jacobians: bool = False,
) -> Projection:
    """Return the pixels of 3D points seen by a camera with distortion (cv2.projectPoints + skew).

    object_points: (..., N, 3) in the world frame; rvec, tvec: (..., 3) world-to-camera pose
    (Xc = R X + t); K: (3, 3) upper triangular; dist: up to 5 coefficients (k1, k2, p1, p2, k3),
    missing ones are zero, or OpenCV's 8, 12 or 14. Batch dimensions (...) are shared by points
    and poses, so one call projects every view of a calibration. With `jacobians=True` the
    derivatives are analytic and vectorised over all points (module docstring for the chain);
    d/d rvec uses the left Jacobian of SO(3), exact at every angle.
    """
    X = np.asarray(object_points, dtype=np.float64)
    rv = np.asarray(rvec, dtype=np.float64)
    tv = np.asarray(tvec, dtype=np.float64)
    Km = np.asarray(K, dtype=np.float64)
    if X.shape[-1] != 3 or rv.shape[-1] != 3 or tv.shape[-1] != 3 or Km.shape != (3, 3):
        raise InvalidInput(
            "project_points needs object_points (..., N, 3), rvec and tvec (..., 3), K (3, 3); "
            f"got {X.shape}, {rv.shape}, {tv.shape}, {Km.shape}"
        )
    intr = np.array([Km[0, 0], Km[1, 1], Km[0, 2], Km[1, 2], Km[0, 1]])
    d = as_distortion_model(dist)
    pts, depth, J = _project(X, rv, tv, intr, d, jacobians)
    if J is None:
        return Projection(points=pts, depth=depth)
    p = 5 + d.size
    return Projection(
        points=pts,
        depth=depth,
        d_intrinsics=J[..., 0:5],
        d_distortion=J[..., 5:p],
        d_pose=J[..., p : p + 6],
    )


def _project(
    X: Array, rv: Array, tv: Array, intr: Array, dist: Array, jacobians: bool
) -> tuple[Array, Array, Array | None]:
    """Return pixels (..., N, 2), depths (..., N) and, if asked, the Jacobian (..., N, 2, 16)
    with columns (fx, fy, cx, cy, skew, k1, k2, p1, p2, k3, rvec, t), (..., N, 2, 25) with the
    fourteen coefficients of a long model.

    The hot path of every calibration: written as few whole-array numpy operations as possible
    (no per-point Python, no stacking of many small arrays), filling one Jacobian array.
    """
    fx, fy, cx, cy, s = (float(v) for v in intr)
    R = rotvec_to_matrix(rv)
    RX = X @ np.swapaxes(R, -1, -2)
    Xc = RX + tv[..., None, :]
    depth = Xc[..., 2]
    iz = 1.0 / depth
    x = Xc[..., 0] * iz
    y = Xc[..., 1] * iz
    xd, yd, rad, r2 = distortion_model(x, y, dist)
    pts = np.empty((*x.shape, 2))
    pts[..., 0] = fx * xd + s * yd + cx
    pts[..., 1] = fy * yd + cy
    if not jacobians:
        return pts, depth, None

    nd = dist.size
    p = 5 + nd  # first pose column
    J = np.zeros((*x.shape, 2, p + 6))
    ju, jv = J[..., 0, :], J[..., 1, :]
    # Intrinsics (fx, fy, cx, cy, skew).
    ju[..., 0] = xd
    ju[..., 2] = 1.0
    ju[..., 4] = yd
    jv[..., 1] = yd
    jv[..., 3] = 1.0
    # Distortion (k1, k2, p1, p2, k3) through [[fx, s], [0, fy]].
    if nd == 14:
        Dc = distortion_coefficient_jacobian(x, y, dist)
        ju[..., 5:p] = fx * Dc[..., 0, :] + s * Dc[..., 1, :]
        jv[..., 5:p] = fy * Dc[..., 1, :]
    else:
        _five_coefficient_columns(ju, jv, x, y, r2, fx, fy, s)
    # d(x_d, y_d) / d(x, y) = [[a11, a12], [a21, a22]].
    a11, a12, a21, a22 = distortion_jacobian(x, y, rad, r2, dist)
    # d(u, v) / d(x, y) = [[fx, s], [0, fy]] @ A, then / d Xc through (x, y) = (X, Y) / Z.
    b11 = (fx * a11 + s * a21) * iz
    b12 = (fx * a12 + s * a22) * iz
    b21 = (fy * a21) * iz
    b22 = (fy * a22) * iz
    ju[..., p + 3] = b11
    ju[..., p + 4] = b12
    ju[..., p + 5] = -(b11 * x + b12 * y)
    jv[..., p + 3] = b21
    jv[..., p + 4] = b22
    jv[..., p + 5] = -(b21 * x + b22 * y)
    # d Xc / d rvec = -[R X]x J_l(rvec): a row d of d(u,v)/d Xc maps to (R X x d)^T J_l.
    d = J[..., p + 3 : p + 6]
    a = RX[..., None, :]
    c = np.empty(d.shape)
    c[..., 0] = a[..., 1] * d[..., 2] - a[..., 2] * d[..., 1]
    c[..., 1] = a[..., 2] * d[..., 0] - a[..., 0] * d[..., 2]
    c[..., 2] = a[..., 0] * d[..., 1] - a[..., 1] * d[..., 0]
    batch = x.shape[:-1]
    Jl = left_jacobian_so3(rv)
    J[..., p : p + 3] = (c.reshape(*batch, -1, 3) @ Jl).reshape(d.shape)
    return pts, depth, J


def _five_coefficient_columns(
    ju: Array, jv: Array, x: Array, y: Array, r2: Array, fx: float, fy: float, s: float
) -> None:
    # d(u, v) / d(k1, k2, p1, p2, k3) into columns 5..9 of the Jacobian's rows ju, jv.
    r4 = r2 * r2
    ux = fx * x + s * y
    vy = fy * y
    ju[..., 5] = ux * r2
    ju[..., 6] = ux * r4
    ju[..., 9] = ux * (r4 * r2)
    jv[..., 5] = vy * r2
    jv[..., 6] = vy * r4
    jv[..., 9] = vy * (r4 * r2)
    xy2 = 2.0 * x * y
    ryy = r2 + 2.0 * y * y
    rxx = r2 + 2.0 * x * x
    ju[..., 7] = fx * xy2 + s * ryy
    ju[..., 8] = fx * rxx + s * xy2
    jv[..., 7] = fy * ryy
    jv[..., 8] = fy * xy2


def undistort_points(
    pixels: ArrayLike,
    K: ArrayLike,
    dist: ArrayLike | None = None,
    *,
    to_pixels: bool = False,
    max_iterations: int = 20,
    tol: float = 1e-15,
    start: tuple[Array, Array] | None = None,
) -> Array:
    """Return ideal (undistorted) normalised coordinates (..., 2) of distorted pixels (..., 2).

    Inverts u = K (x_d, y_d, 1) exactly, then the distortion x_d = D(x) by Newton's method on the
    2x2 analytic Jacobian, vectorised over all points, to machine precision (cv2.undistortPoints
    uses a fixed-point iteration with a fixed count instead). With `to_pixels` the result is
    mapped back through K without distortion: ideal pixels K (x, y, 1). Raises ConvergenceError
    when Newton does not converge (distortion so strong that D is not invertible there).
    Newton stops once its largest step is under `tol` times the largest coordinate (at least 1);
    convergence being quadratic, what is left then is of the order of that step's square, so
    1e-10 already gives machine precision, one iteration sooner than the default. Newton starts
    from the distorted coordinates, or from `start` (x, y) (each (...)): ideal coordinates known
    to be near (interpolated from a grid, say), from which it needs fewer iterations.
    """
    uv = np.asarray(pixels, dtype=np.float64)
    Km = np.asarray(K, dtype=np.float64)
    if uv.shape[-1] != 2 or Km.shape != (3, 3):
        raise InvalidInput(f"pixels must be (..., 2) and K (3, 3); got {uv.shape}, {Km.shape}")
    fx, s, cx = Km[0, 0], Km[0, 1], Km[0, 2]
    fy, cy = Km[1, 1], Km[1, 2]
    d = as_distortion_model(dist)
    yd = (uv[..., 1] - cy) / fy
    xd = (uv[..., 0] - cx - s * yd) / fx
    if start is None:
        x, y = xd.copy(), yd.copy()
    else:
        x, y = (np.array(v, dtype=np.float64) for v in start)
    if np.any(d):
        scale = max(1.0, float(np.max(np.abs(xd), initial=0.0)))
        scale = max(scale, float(np.max(np.abs(yd), initial=0.0)))
        step = np.inf
        for _ in range(max_iterations):
            fx_d, fy_d, rad, r2 = distortion_model(x, y, d)
            ex = fx_d - xd
            ey = fy_d - yd
            a11, a12, a21, a22 = distortion_jacobian(x, y, rad, r2, d)
            det = a11 * a22 - a12 * a21
            dx = (a22 * ex - a12 * ey) / det
            dy = (a11 * ey - a21 * ex) / det
            x -= dx
            y -= dy
            step = float(np.max(np.abs(np.stack([dx, dy])), initial=0.0))
            if not np.isfinite(step):
                break
            if step <= tol * scale:
                break
        if not np.isfinite(step) or step > 1e-9 * scale:
            raise ConvergenceError(
                "undistortion did not converge; the distortion is not invertible at these pixels"
            )
    if to_pixels:
        return np.stack([fx * x + s * y + cx, fy * y + cy], -1)
    return np.stack([x, y], -1)


@dataclass(frozen=True)
class Pose:
    """A world-to-camera rigid transform Xc = R X + t (for a plane: plane-to-camera).

    R: (..., 3, 3) rotation; t: (..., 3) translation in the world's length unit. `rvec` is the
    rotation vector (..., 3) of R (axis times angle, radians), as cv2.Rodrigues returns it.
    """

    R: Array
    t: Array

    @property
    def rvec(self) -> Array:
        """Rotation vector (..., 3) of R, angle in [0, pi]."""
        return matrix_to_rotvec(self.R)


class ReprojectionProblem:
    """Reprojection error of m views of known points, for `core.optim.solve_sparse_lm`.

    Global block: the free camera parameters g (p,), mapped to the full parameter vector
    (fx, fy, cx, cy, skew, k1, k2, p1, p2, k3) by `full = base + P g` (P (10, p) selects free
    parameters and may tie some, e.g. fx = fy). Local block j: the pose of view j,
    (rvec (3), t (3)). Residual block j: the 2 N_max pixel differences (projected - observed),
    interleaved (u, v) per point; views with fewer points are padded with zero rows.
    """

    def __init__(
        self,
        object_points: Array,
        image_points: Array,
        mask: Array,
        base: Array,
        selection: Array,
    ) -> None:
        self.X = object_points  # (m, N, 3)
        self.uv = image_points  # (m, N, 2)
        self.w = mask.astype(np.float64)[..., None]  # (m, N, 1)
        self.padded = not bool(np.all(mask))
        self.base = base
        self.P = selection
        # A plain selection (one 1 per column, in a row of its own) is applied by indexing.
        plain = np.all((selection == 0) | (selection == 1)) and np.all(selection.sum(0) == 1)
        plain = plain and np.all(selection.sum(1) <= 1)
        self.columns = np.argmax(selection, 0) if plain and selection.shape[1] else None
        m, n = mask.shape
        self.shape = (m, 2 * n)

    def full(self, g: Array) -> Array:
        """Return the 10 camera parameters for global parameters g."""
        return self.base + self.P @ g

    def _project(self, g: Array, loc: Array, jac: bool) -> tuple[Array, Array | None]:
        f = self.full(g)
        pts, _, J = _project(self.X, loc[:, :3], loc[:, 3:], f[:5], f[5:], jac)
        res = pts - self.uv
        if self.padded:
            res *= self.w
            if J is not None:
                J *= self.w[..., None]
        return res.reshape(self.shape), J

    def residuals(self, x_global: Array, x_local: Array) -> Array:
        """Return the residuals, shape (m, 2 N_max), pixels."""
        return self._project(x_global, x_local, False)[0]

    def jacobians(self, x_global: Array, x_local: Array) -> tuple[Array, Array, Array]:
        """Return residuals (m, 2N), d/d global (m, 2N, p) and d/d pose (m, 2N, 6)."""
        res, J = self._project(x_global, x_local, True)
        assert J is not None
        m, r = self.shape
        if self.columns is not None:
            jg = J[..., self.columns].reshape(m, r, -1)
        else:
            jg = (J[..., :10] @ self.P).reshape(m, r, -1)
        return res, jg, J[..., 10:].reshape(m, r, 6)
