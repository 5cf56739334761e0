"""Image conics of circles: ellipse fitting, the projected centre of concentric circles from a
pair of conics, and the supporting plane's normal and distance from a circle of known radius.

Conics are symmetric 3x3 matrices C with x^T C x = 0 for homogeneous points x on the curve.
In normalised camera coordinates (x = K^-1 u) the conic Q = K^T C K is the cone of rays
through the circle.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_points
from core.errors import DegenerateConfiguration

Array = NDArray[np.float64]


def conic_matrix(c: ArrayLike) -> Array:
    """Return the symmetric conic matrices (..., 3, 3) of coefficients (..., 6) of
    a x^2 + b x y + c y^2 + d x + e y + f = 0."""
    p = np.asarray(c, dtype=np.float64)
    a, b, cc, d, e, f = (p[..., i] for i in range(6))
    return np.stack(
        [
            np.stack([a, b / 2, d / 2], -1),
            np.stack([b / 2, cc, e / 2], -1),
            np.stack([d / 2, e / 2, f], -1),
        ],
        -2,
    )


# The conics of the six unit coefficient vectors (conic_matrix is linear in them).
_BASIS = conic_matrix(np.eye(6))


@dataclass(frozen=True)
class ConicFit:
    """An ellipse fitted to edge points.

    C: (3, 3) conic in the points' pixel frame, scaled to unit Frobenius norm (sign: C[2, 2] < 0
    inside positive, i.e. x^T C x < 0 at the centre); cov: (6, 6) covariance of the six
    coefficients (a, b, c, d, e, f) of C's normalised form (in the tangent space of the unit
    sphere); rms: root mean square Sampson distance of the points (pixels, the first-order
    geometric distance); n: points used.
    """

    C: Array
    rms: float
    n: int
    cov: Array = field(repr=False)

    @property
    def centre(self) -> Array:
        """Return the ellipse's centre (2,) pixels: the pole of the line at infinity."""
        c = np.asarray(np.linalg.solve(self.C[:2, :2], -self.C[:2, 2]), dtype=np.float64)
        return c


def fit_ellipse(points: ArrayLike, *, iterations: int = 10) -> ConicFit:
    """Return the ellipse through N >= 6 edge points (N, 2), pixels.

    Algebraic start: Fitzgibbon, Pilu & Fisher 1999 (the ellipse-specific direct least squares,
    b^2 - 4ac < 0 enforced) in the numerically stable form of Halir & Flusser 1998, on points
    centred and scaled to unit RMS radius. Then Gauss-Newton on the Sampson distance
    r_i = x_i^T C x_i / ||2 (C x_i)_{1,2}|| (the first-order geometric distance, H&Z sec. 4.2.6)
    over the conic on the unit sphere. The covariance is sigma^2 (J^T J)^+ with sigma^2 the
    residual variance. Raises DegenerateConfiguration when the points are not on an ellipse.
    """
    p = as_points(points, 2, "points", min_count=6)
    mu = p.mean(0)
    s = float(np.sqrt(np.mean(np.sum((p - mu) ** 2, 1))))
    if s <= 0:
        raise DegenerateConfiguration("the edge points coincide; no ellipse")
    q = (p - mu) / s
    x, y = q[:, 0], q[:, 1]
    D1 = np.stack([x * x, x * y, y * y], 1)
    D2 = np.stack([x, y, np.ones_like(x)], 1)
    S1, S2, S3 = D1.T @ D1, D1.T @ D2, D2.T @ D2
    try:
        T = -np.linalg.solve(S3, S2.T)
    except np.linalg.LinAlgError:
        raise DegenerateConfiguration("the edge points are collinear; no ellipse") from None
    M = S1 + S2 @ T
    M = np.array([M[2] / 2, -M[1], M[0] / 2])
    _, v = np.linalg.eig(M)
    v = np.real(v)
    cond = 4 * v[0] * v[2] - v[1] ** 2
    ok = np.flatnonzero(cond > 0)
    if ok.size == 0:
        raise DegenerateConfiguration("the edge points do not lie on an ellipse")
    a1 = v[:, ok[0]]
    c = np.concatenate([a1, T @ a1])
    c /= np.linalg.norm(c)
    # The monomials and the Jacobian are stored one row per coefficient (6, N): every update
    # below is then an operation on contiguous rows.
    n = len(x)
    M2 = np.empty((6, n))
    np.multiply(x, x, out=M2[0])
    np.multiply(x, y, out=M2[1])
    np.multiply(y, y, out=M2[2])
    M2[3], M2[4], M2[5] = x, y, 1.0
    two_x, two_y = 2.0 * x, 2.0 * y

    def residuals(c: Array) -> tuple[Array, Array, Array, Array]:
        # f = x^T C x, its gradient (d/dx, d/dy) and the Sampson distance r = f / |gradient|.
        f = c @ M2
        gx = c[0] * two_x
        gx += c[1] * y
        gx += c[3]
        gy = c[1] * x
        gy += c[2] * two_y
        gy += c[4]
        inv_g = gx * gx
        inv_g += gy * gy
        np.sqrt(inv_g, out=inv_g)
        np.divide(1.0, inv_g, out=inv_g)
        return f * inv_g, gx, gy, inv_g

    J = np.empty((6, n))
    r = np.zeros(n)
    for _ in range(iterations):
        r, gx, gy, inv_g = residuals(c)
        # d r / d c = M2 / g - f / g^3 (gx d gx / d c + gy d gy / d c), with f / g^3 = r / g^2.
        np.multiply(M2, inv_g, out=J)
        w = r * inv_g
        w *= inv_g
        wx, wy = w * gx, w * gy
        J[0] -= wx * two_x
        J[1] -= wx * y + wy * x
        J[2] -= wy * two_y
        J[3] -= wx
        J[4] -= wy
        # Normal equations in the tangent space of the unit sphere (c c^T fills the null
        # direction of the scale, so the 6x6 system is regular and the step is tangent).
        A = J @ J.T
        step = np.linalg.solve(A + np.trace(A) * np.outer(c, c), -(J @ r))
        c = c + step
        c /= np.linalg.norm(c)
        # Gauss-Newton converges quadratically here: after a step under 1e-7, what remains is of
        # its square, far below the fit's own noise.
        if np.linalg.norm(step) < 1e-7:
            break
    r, _, _, _ = residuals(c)
    J = J.T
    sigma2 = float(r @ r) / max(n - 5, 1)
    # The pseudo-inverse of P A P (P = I - c c^T, the tangent space): P A P and c c^T act on
    # orthogonal subspaces, so (P A P + c c^T)^-1 = (P A P)^+ + c c^T.
    cc = np.outer(c, c)
    P = np.eye(6) - cc
    cov_n = sigma2 * (np.linalg.inv(P @ (J.T @ J) @ P + cc) - cc)
    # Back to pixels: C_pix = A^T C_n A with A = [[1/s, 0, -mu/s], [0, 1/s, ...], [0, 0, 1]].
    A = np.array([[1 / s, 0, -mu[0] / s], [0, 1 / s, -mu[1] / s], [0, 0, 1]])
    Cn = (c @ _BASIS.reshape(6, 9)).reshape(3, 3)
    Cp = A.T @ Cn @ A
    # The linear map of coefficients c_n -> c_pix, for the covariance (before normalisation).
    E = A.T @ _BASIS @ A  # the six basis conics, mapped
    L = np.stack(
        [E[:, 0, 0], 2 * E[:, 0, 1], E[:, 1, 1], 2 * E[:, 0, 2], 2 * E[:, 1, 2], E[:, 2, 2]], 0
    )
    norm = float(np.linalg.norm(Cp))
    Cp = Cp / norm
    L = L / norm
    centre_val = _conic_at_centre(Cp)
    if centre_val > 0:
        Cp, L = -Cp, -L
    if np.linalg.det(Cp[:2, :2]) <= 0:
        raise DegenerateConfiguration("the fitted conic is not an ellipse")
    return ConicFit(C=Cp, rms=float(np.sqrt(np.mean(r * r))) * s, n=n, cov=L @ cov_n @ L.T)


def _conic_at_centre(C: Array) -> float:
    c = np.linalg.solve(C[:2, :2], -C[:2, 2])
    x = np.array([c[0], c[1], 1.0])
    return float(x @ C @ x)


def concentric_centre(Q1: ArrayLike, Q2: ArrayLike) -> Array:
    """Return the image (homogeneous (..., 3), last coordinate 1) of the common centre of two
    concentric circles from their image conics Q1, Q2 (..., 3, 3) (stacks of pairs at once).

    The pencil Q1 - lambda Q2 of two concentric circles has a double eigenvalue (its
    eigenvectors span the line at infinity of the plane) and a simple one whose eigenvector is
    the centre (in the plane, Q2^-1 Q1 = diag(1, 1, r1^2 / r2^2) up to scale; a homography H
    conjugates it, Q2'^-1 Q1' = H (Q2^-1 Q1) H^-1). So the centre is the eigenvector of
    Q2^-1 Q1 whose eigenvalue is farthest from the other two. Unlike the ellipse centres, it
    is the true projection of the circles' centre (no perspective bias).
    """
    A = np.linalg.solve(np.asarray(Q2, dtype=np.float64), np.asarray(Q1, dtype=np.float64))
    w, v = np.linalg.eig(A)
    d = np.abs(w[..., :, None] - w[..., None, :])
    d[..., [0, 1, 2], [0, 1, 2]] = np.inf
    k = np.argmax(d.min(-1), -1)
    c = np.real(np.take_along_axis(v, k[..., None, None], -1)[..., 0])
    if np.any(np.abs(c[..., 2]) < 1e-12):
        raise DegenerateConfiguration("the circles' centre is at infinity: the plane is edge-on")
    return np.asarray(c / c[..., 2:3], dtype=np.float64)


def circle_normals(Q: ArrayLike) -> tuple[Array, Array]:
    """Return the two unit normals (..., 3) of the planes that cut the cone Q (..., 3, 3)
    (normalised camera coordinates) in a circle, each oriented toward the camera
    (n . ray < 0).

    With Q = V diag(l1, l2, l3) V^T, l1 >= l2 > 0 > l3 (sign of Q chosen so), subtracting l2
    times the identity factors the form into two planes, so the circular sections have normals
    V (+-sqrt(l1 - l2), 0, sqrt(l2 - l3)) (the classic two-fold ambiguity of a single circle;
    Safaee-Rad et al. 1992, Shiu & Ahmad 1989).
    """
    Qm = np.asarray(Q, dtype=np.float64)
    w, V = np.linalg.eigh(Qm)
    flip = np.sum(w > 0, -1) == 1
    if np.any(flip):
        Qm = np.where(flip[..., None, None], -Qm, Qm)
        w, V = np.linalg.eigh(Qm)
    if not np.all((w[..., 2] >= w[..., 1]) & (w[..., 1] > 0) & (w[..., 0] < 0)):
        raise DegenerateConfiguration(
            "the conic is not the image of a circle in front of the camera"
        )
    l1, l2, l3 = w[..., 2:3], w[..., 1:2], w[..., 0:1]
    e1, e3 = V[..., 2], V[..., 0]
    a = np.sqrt(np.maximum(l1 - l2, 0.0))
    b = np.sqrt(l2 - l3)
    axis = np.where(e3[..., 2:3] > 0, e3, -e3)  # the cone's axis, pointing forward
    out = []
    for sgn in (1.0, -1.0):
        n = sgn * a * e1 + b * e3
        n = n / np.linalg.norm(n, axis=-1, keepdims=True)
        n = np.where(np.sum(n * axis, -1, keepdims=True) > 0, -n, n)
        out.append(n)
    return out[0], out[1]


def circle_distance(Q: ArrayLike, n: ArrayLike, m: ArrayLike, radius: float) -> Array | float:
    """Return the depth factor t (..., the circle's centre is t m) of a circle of `radius` with
    plane normal n (..., 3) whose centre's ray is m (..., 3, with m[2] = 1), from its cone Q
    (..., 3, 3); a float for single inputs.

    With u, v an orthonormal basis of the plane and H = [u v t m] mapping the plane's (x, y, 1)
    to rays, H^T Q H is proportional to diag(1, 1, -radius^2), so
    t = radius sqrt(-(u^T Q u + v^T Q v) / 2 / (m^T Q m)).
    """
    Qm = np.asarray(Q, dtype=np.float64)
    nn = np.asarray(n, dtype=np.float64)
    mm = np.asarray(m, dtype=np.float64)
    # u^T Q u + v^T Q v = trace(Q) - n^T Q n for any orthonormal basis (u, v, n).
    a = (np.trace(Qm, axis1=-2, axis2=-1) - np.einsum("...i,...ij,...j", nn, Qm, nn)) / 2
    mq = np.einsum("...i,...ij,...j", mm, Qm, mm)
    if np.any(a * mq >= 0):
        raise DegenerateConfiguration("the circle's centre ray is not inside its image conic")
    t = radius * np.sqrt(-a / mq)
    return float(t) if np.ndim(t) == 0 else np.asarray(t, dtype=np.float64)
