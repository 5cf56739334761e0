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

Parameter orders used throughout: intrinsics (fx, fy, cx, cy, s); distortion (k1, k2, p1, p2,
k3) as OpenCV; pose (rvec (3), t (3)).
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


def distort_normalized(xy: ArrayLike, dist: ArrayLike | None) -> Array:
    """Return distorted normalised coordinates (..., 2) of ideal ones xy (..., 2).

    OpenCV's radial (k1, k2, k3) and tangential (p1, p2) model, see the module docstring.
    """
    p = np.asarray(xy, dtype=np.float64)
    k1, k2, p1, p2, k3 = as_distortion(dist)
    x, y = p[..., 0], p[..., 1]
    xx, yy, xy2 = x * x, y * y, 2.0 * x * y
    r2 = xx + yy
    rad = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * rad + p1 * xy2 + p2 * (r2 + 2.0 * xx)
    yd = y * rad + p1 * (r2 + 2.0 * yy) + p2 * xy2
    return np.stack([xd, yd], -1)


@dataclass(frozen=True)
class Projection:
    """Projected pixels and, if requested, their analytic Jacobians.

    Shapes for a batch (...,) of N points: `points` (..., N, 2) pixels; `d_intrinsics`
    (..., N, 2, 5) wrt (fx, fy, cx, cy, skew); `d_distortion` (..., N, 2, 5) wrt
    (k1, k2, p1, p2, k3); `d_pose` (..., N, 2, 6) wrt (rvec, t); `depth` (..., N) the camera-frame
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
    missing ones are zero. Batch dimensions (...) are shared by points and poses, so one call
    projects every view of a calibration. With `jacobians=True` the derivatives are analytic and
    vectorised over all points (module docstring for the chain); d/d rvec uses the left Jacobian
    of SO(3), exact at every angle.
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
    fx, s, cx = Km[0, 0], Km[0, 1], Km[0, 2]
    fy, cy = Km[1, 1], Km[1, 2]
    k1, k2, p1, p2, k3 = as_distortion(dist)

    R = rotvec_to_matrix(rv)
    RX = np.einsum("...ij,...nj->...ni", R, X)
    Xc = RX + tv[..., None, :]
    iz = 1.0 / Xc[..., 2]
    x = Xc[..., 0] * iz
    y = Xc[..., 1] * iz
    xx, yy, xy = x * x, y * y, x * y
    r2 = xx + yy
    r4 = r2 * r2
    rad = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * rad + 2.0 * p1 * xy + p2 * (r2 + 2.0 * xx)
    yd = y * rad + p1 * (r2 + 2.0 * yy) + 2.0 * p2 * xy
    u = fx * xd + s * yd + cx
    v = fy * yd + cy
    pts = np.stack([u, v], -1)
    if not jacobians:
        return Projection(points=pts, depth=Xc[..., 2])

    shape = x.shape
    one = np.ones(shape)
    zero = np.zeros(shape)
    # d(u, v) / d(fx, fy, cx, cy, s)
    d_int = np.stack(
        [np.stack([xd, zero, one, zero, yd], -1), np.stack([zero, yd, zero, one, zero], -1)], -2
    )
    # d(x_d, y_d) / d(k1, k2, p1, p2, k3), then through [[fx, s], [0, fy]].
    r6 = r4 * r2
    dx_dk = np.stack([x * r2, x * r4, 2.0 * xy, r2 + 2.0 * xx, x * r6], -1)
    dy_dk = np.stack([y * r2, y * r4, r2 + 2.0 * yy, 2.0 * xy, y * r6], -1)
    d_dist = np.stack([fx * dx_dk + s * dy_dk, fy * dy_dk], -2)
    # d(x_d, y_d) / d(x, y)
    drad = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
    a11 = rad + 2.0 * xx * drad + 2.0 * p1 * y + 6.0 * p2 * x
    a12 = 2.0 * xy * drad + 2.0 * p1 * x + 2.0 * p2 * y
    a22 = rad + 2.0 * yy * drad + 6.0 * p1 * y + 2.0 * p2 * x
    # d(u, v) / d(x, y) = [[fx, s], [0, fy]] @ [[a11, a12], [a12, a22]]
    b11 = fx * a11 + s * a12
    b12 = fx * a12 + s * a22
    b21 = fy * a12
    b22 = fy * a22
    # d(u, v) / d Xc = d(u, v)/d(x, y) @ [[iz, 0, -x iz], [0, iz, -y iz]]
    du = np.stack([b11 * iz, b12 * iz, -(b11 * x + b12 * y) * iz], -1)
    dv = np.stack([b21 * iz, b22 * iz, -(b21 * x + b22 * y) * iz], -1)
    dXc = np.stack([du, dv], -2)  # (..., N, 2, 3)
    # d Xc / d rvec = -[R X]x J_l(rvec); a row m of dXc times -[a]x is (a x m)^T.
    Jl = left_jacobian_so3(rv)  # (..., 3, 3)
    cross = np.cross(RX[..., None, :], dXc)  # (..., N, 2, 3)
    d_rvec = cross @ Jl[..., None, :, :]
    d_pose = np.concatenate([d_rvec, dXc], -1)
    return Projection(
        points=pts, depth=Xc[..., 2], d_intrinsics=d_int, d_distortion=d_dist, d_pose=d_pose
    )


def undistort_points(
    pixels: ArrayLike,
    K: ArrayLike,
    dist: ArrayLike | None = None,
    *,
    to_pixels: bool = False,
    max_iterations: int = 20,
) -> Array:
    """Return ideal (undistorted) normalised coordinates (..., 2) of distorted pixels (..., 2).

    Inverts u = K (x_d, y_d, 1) exactly, then the distortion x_d = D(x) by Newton's method on the
    2x2 analytic Jacobian, vectorised over all points, to machine precision (cv2.undistortPoints
    uses a fixed-point iteration with a fixed count instead). With `to_pixels` the result is
    mapped back through K without distortion: ideal pixels K (x, y, 1). Raises ConvergenceError
    when Newton does not converge (distortion so strong that D is not invertible there).
    """
    uv = np.asarray(pixels, dtype=np.float64)
    Km = np.asarray(K, dtype=np.float64)
    if uv.shape[-1] != 2 or Km.shape != (3, 3):
        raise InvalidInput(f"pixels must be (..., 2) and K (3, 3); got {uv.shape}, {Km.shape}")
    fx, s, cx = Km[0, 0], Km[0, 1], Km[0, 2]
    fy, cy = Km[1, 1], Km[1, 2]
    k1, k2, p1, p2, k3 = as_distortion(dist)
    yd = (uv[..., 1] - cy) / fy
    xd = (uv[..., 0] - cx - s * yd) / fx
    x, y = xd.copy(), yd.copy()
    if np.any(as_distortion(dist)):
        scale = max(1.0, float(np.max(np.abs(xd), initial=0.0)))
        scale = max(scale, float(np.max(np.abs(yd), initial=0.0)))
        step = np.inf
        for _ in range(max_iterations):
            xx, yy, xy = x * x, y * y, x * y
            r2 = xx + yy
            rad = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            ex = x * rad + 2.0 * p1 * xy + p2 * (r2 + 2.0 * xx) - xd
            ey = y * rad + p1 * (r2 + 2.0 * yy) + 2.0 * p2 * xy - yd
            drad = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
            a11 = rad + 2.0 * xx * drad + 2.0 * p1 * y + 6.0 * p2 * x
            a12 = 2.0 * xy * drad + 2.0 * p1 * x + 2.0 * p2 * y
            a22 = rad + 2.0 * yy * drad + 6.0 * p1 * y + 2.0 * p2 * x
            det = a11 * a22 - a12 * a12
            dx = (a22 * ex - a12 * ey) / det
            dy = (a11 * ey - a12 * ex) / det
            x -= dx
            y -= dy
            step = float(np.max(np.abs(np.stack([dx, dy])), initial=0.0))
            if not np.isfinite(step):
                break
            if step <= 1e-15 * scale:
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
        self.base = base
        self.P = selection
        m, n = mask.shape
        self.shape = (m, 2 * n)

    def full(self, g: Array) -> Array:
        """Return the 10 camera parameters for global parameters g."""
        return self.base + self.P @ g

    def _project(self, g: Array, loc: Array, jac: bool) -> Projection:
        f = self.full(g)
        return project_points(
            self.X, loc[:, :3], loc[:, 3:], intrinsics_to_matrix(f[:5]), f[5:], jacobians=jac
        )

    def residuals(self, x_global: Array, x_local: Array) -> Array:
        """Return the residuals, shape (m, 2 N_max), pixels."""
        pr = self._project(x_global, x_local, False)
        return ((pr.points - self.uv) * self.w).reshape(self.shape)

    def jacobians(self, x_global: Array, x_local: Array) -> tuple[Array, Array, Array]:
        """Return residuals (m, 2N), d/d global (m, 2N, p) and d/d pose (m, 2N, 6)."""
        pr = self._project(x_global, x_local, True)
        assert pr.d_intrinsics is not None and pr.d_distortion is not None
        assert pr.d_pose is not None
        res = ((pr.points - self.uv) * self.w).reshape(self.shape)
        w = self.w[..., None]
        jf = np.concatenate([pr.d_intrinsics, pr.d_distortion], -1) * w
        jg = (jf @ self.P).reshape(*self.shape, self.P.shape[1])
        jl = (pr.d_pose * w).reshape(*self.shape, 6)
        return res, jg, jl
