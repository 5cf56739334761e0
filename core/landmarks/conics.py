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
from core.errors import DegenerateConfiguration, InvalidInput

Array = NDArray[np.float64]


# The conics of the six unit coefficient vectors (conic_matrix is linear in them), as the rows
# of a (6, 9) matrix.
_BASIS9 = np.array(
    [
        [1.0, 0, 0, 0, 0, 0, 0, 0, 0],
        [0, 0.5, 0, 0.5, 0, 0, 0, 0, 0],
        [0, 0, 0, 0, 1.0, 0, 0, 0, 0],
        [0, 0, 0.5, 0, 0, 0, 0.5, 0, 0],
        [0, 0, 0, 0, 0, 0.5, 0, 0.5, 0],
        [0, 0, 0, 0, 0, 0, 0, 0, 1.0],
    ]
)
_BASIS = _BASIS9.reshape(6, 3, 3)


def conic_matrix(c: ArrayLike) -> Array:
    """Return the symmetric conic matrices (..., 3, 3) of coefficients (..., 6) of
    a x^2 + b x y + c y^2 + d x + e y + f = 0."""
    p = np.asarray(c, dtype=np.float64)
    # (one product: each entry is one coefficient, or half of one, exactly)
    return np.asarray((p @ _BASIS9).reshape(*p.shape[:-1], 3, 3), dtype=np.float64)


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
        return _centre(self.C)


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
    fit = fit_ellipses([p], iterations=iterations)[0]
    if isinstance(fit, str):
        raise DegenerateConfiguration(fit)
    return fit


def fit_ellipses(points: list[Array], *, iterations: int = 10) -> list[ConicFit | str]:
    """Return the ellipse (as fit_ellipse) through each set of edge points (N_i >= 6, 2), or
    the reason (str) why a set is not on an ellipse: all sets solved together, the shorter ones
    padded with zero-weight points (numpy's per-call cost, not arithmetic, is what a fit of a
    few hundred points costs)."""
    F = len(points)
    if F == 0:
        return []
    counts = np.array([len(q) for q in points])
    if np.any(counts < 6):
        raise InvalidInput("each point set needs at least 6 points for an ellipse")
    width = int(counts.max())
    w = (np.arange(width) < counts[:, None]).astype(np.float64)  # (F, N) 1 real, 0 padding
    P = np.zeros((F, width, 2))
    for f, q in enumerate(points):
        P[f, : len(q)] = q
    reason: list[str | None] = [None] * F
    n_f = counts.astype(np.float64)
    mu = np.sum(P, 1) / n_f[:, None]
    d = (P - mu[:, None, :]) * w[..., None]
    s = np.sqrt(np.sum(d * d, (1, 2)) / n_f)
    for f in np.flatnonzero(~(s > 0)).tolist():
        reason[f] = "the edge points coincide; no ellipse"
    s = np.where(s > 0, s, 1.0)
    q = d / s[:, None, None]  # zero at the padding
    x, y = q[..., 0], q[..., 1]
    D1 = np.stack([x * x, x * y, y * y], 1)  # (F, 3, N)
    D2 = np.stack([x, y, w], 1)
    S1 = D1 @ np.swapaxes(D1, 1, 2)
    S2 = D1 @ np.swapaxes(D2, 1, 2)
    S3 = D2 @ np.swapaxes(D2, 1, 2)
    singular = ~(np.abs(np.linalg.det(S3)) > 1e-300)
    for f in np.flatnonzero(singular).tolist():
        reason[f] = reason[f] or "the edge points are collinear; no ellipse"
    S3[singular] = np.eye(3)
    try:
        T = -np.linalg.solve(S3, np.swapaxes(S2, 1, 2))
    except np.linalg.LinAlgError:
        # A set so close to collinear that LAPACK finds S3 singular: each alone.
        T = np.empty((F, 3, 3))
        for f in range(F):
            try:
                T[f] = -np.linalg.solve(S3[f], S2[f].T)
            except np.linalg.LinAlgError:
                reason[f] = reason[f] or "the edge points are collinear; no ellipse"
                T[f] = 0.0
    M = S1 + S2 @ T
    M = np.stack([M[:, 2] / 2, -M[:, 1], M[:, 0] / 2], 1)
    _, v = np.linalg.eig(M)
    v = np.real(v)
    cond = 4 * v[:, 0] * v[:, 2] - v[:, 1] ** 2  # (F, 3), one per eigenvector
    ok = cond > 0
    for f in np.flatnonzero(~ok.any(1)).tolist():
        reason[f] = reason[f] or "the edge points do not lie on an ellipse"
    a1 = np.take_along_axis(v, np.argmax(ok, 1)[:, None, None], 2)[..., 0]  # (F, 3)
    c = np.concatenate([a1, np.einsum("fij,fj->fi", T, a1)], 1)
    c /= np.linalg.norm(c, axis=1, keepdims=True)
    # The monomials and the Jacobian are stored one row per coefficient (F, 6, N): every update
    # below is then an operation on contiguous rows.
    M2 = np.empty((F, 6, width))
    np.multiply(x, x, out=M2[:, 0])
    np.multiply(x, y, out=M2[:, 1])
    np.multiply(y, y, out=M2[:, 2])
    M2[:, 3], M2[:, 4], M2[:, 5] = x, y, w
    two_x, two_y = 2.0 * x, 2.0 * y
    pad = 1.0 - w
    failed = np.array([m is not None for m in reason])
    c[failed] = np.array([1.0, 0.0, 1.0, 0.0, 0.0, -1.0]) / np.sqrt(3.0)  # a circle, unused
    pad[failed] = 1.0

    def residuals(c: Array) -> tuple[Array, Array, Array, Array]:
        # f = x^T C x, its gradient (d/dx, d/dy) and the Sampson distance r = f / |gradient|
        # (zero at the padding).
        cc = c[:, :, None]
        fv = np.einsum("fk,fkn->fn", c, M2)
        gx = cc[:, 0] * two_x
        gx += cc[:, 1] * y
        gx += cc[:, 3]
        gy = cc[:, 1] * x
        gy += cc[:, 2] * two_y
        gy += cc[:, 4]
        inv_g = gx * gx
        inv_g += gy * gy
        inv_g += pad  # never 0 / 0 at the padding (1 there, 0 at the points)
        np.sqrt(inv_g, out=inv_g)
        np.divide(w, inv_g, out=inv_g)
        return fv * inv_g, gx, gy, inv_g

    J = np.empty((F, 6, width))
    r = np.zeros((F, width))
    active = ~failed
    eye_c = np.empty((F, 6, 6))
    for _ in range(iterations):
        r, gx, gy, inv_g = residuals(c)
        # d r / d c = M2 / g - f / g^3 (gx d gx / d c + gy d gy / d c), with f / g^3 = r / g^2.
        np.multiply(M2, inv_g[:, None, :], out=J)
        wr = r * inv_g
        wr *= inv_g
        wx, wy = wr * gx, wr * gy
        J[:, 0] -= wx * two_x
        J[:, 1] -= wx * y + wy * x
        J[:, 2] -= wy * two_y
        J[:, 3] -= wx
        J[:, 4] -= wy
        # Normal equations in the tangent space of the unit sphere (c c^T fills the null
        # direction of the scale, so the 6x6 system is regular and the step is tangent).
        A = J @ np.swapaxes(J, 1, 2)
        np.multiply(c[:, :, None], c[:, None, :], out=eye_c)
        eye_c *= np.trace(A, axis1=1, axis2=2)[:, None, None]
        rhs = -np.einsum("fkn,fn->fk", J, r)
        try:
            step = np.linalg.solve(A + eye_c, rhs[..., None])[..., 0]
        except np.linalg.LinAlgError:
            step = np.zeros_like(c)
            for f in np.flatnonzero(active).tolist():
                try:
                    step[f] = np.linalg.solve(A[f] + eye_c[f], rhs[f])
                except np.linalg.LinAlgError:
                    reason[f] = reason[f] or "the edge points do not lie on an ellipse"
                    active[f] = False
        # Each set stops on its own: after a step under 1e-7, what remains is of its square
        # (Gauss-Newton converges quadratically here), far below the fit's own noise.
        step[~active] = 0.0
        c = c + step
        c /= np.linalg.norm(c, axis=1, keepdims=True)
        active &= np.linalg.norm(step, axis=1) >= 1e-7
        if not active.any():
            break
    r, _, _, _ = residuals(c)
    sigma2 = np.sum(r * r, 1) / np.maximum(n_f - 5, 1)
    # The pseudo-inverse of P A P (P = I - c c^T, the tangent space): P A P and c c^T act on
    # orthogonal subspaces, so (P A P + c c^T)^-1 = (P A P)^+ + c c^T.
    cc = c[:, :, None] * c[:, None, :]
    Pt = np.eye(6) - cc
    # (J is the last iteration's: its normal matrix is A's)
    JJ = A if iterations > 0 else J @ np.swapaxes(J, 1, 2)
    N = Pt @ JJ @ Pt + cc
    bad = ~(np.abs(np.linalg.det(N)) > 1e-300)
    N[bad] = np.eye(6)
    cov_n = sigma2[:, None, None] * (np.linalg.inv(N) - cc)
    # Back to pixels: C_pix = A^T C_n A with A = [[1/s, 0, -mu/s], [0, 1/s, ...], [0, 0, 1]].
    A = np.zeros((F, 3, 3))
    A[:, 0, 0] = A[:, 1, 1] = 1 / s
    A[:, :2, 2] = -mu / s[:, None]
    A[:, 2, 2] = 1.0
    At = np.swapaxes(A, 1, 2)
    Cn = (c @ _BASIS9).reshape(F, 3, 3)
    Cp = At @ Cn @ A
    # The linear map of coefficients c_n -> c_pix, for the covariance (before normalisation).
    E = At[:, None] @ _BASIS @ A[:, None]  # (F, 6, 3, 3) the six basis conics, mapped
    L = np.stack(
        [
            E[:, :, 0, 0],
            2 * E[:, :, 0, 1],
            E[:, :, 1, 1],
            2 * E[:, :, 0, 2],
            2 * E[:, :, 1, 2],
            E[:, :, 2, 2],
        ],
        1,
    )
    norm = np.linalg.norm(Cp, axis=(1, 2))
    Cp = Cp / norm[:, None, None]
    L = L / norm[:, None, None]
    rms = np.sqrt(np.sum(r * r, 1) / n_f) * s
    out: list[ConicFit | str] = []
    for f in range(F):
        if reason[f] is not None or bad[f]:
            out.append(reason[f] or "the fitted conic is not an ellipse")
            continue
        Cf, Lf = Cp[f], L[f]
        if Cf[0, 0] * Cf[1, 1] - Cf[0, 1] * Cf[1, 0] <= 0:
            out.append("the fitted conic is not an ellipse")
            continue
        if _conic_at_centre(Cf) > 0:
            Cf, Lf = -Cf, -Lf
        out.append(ConicFit(C=Cf, rms=float(rms[f]), n=int(counts[f]), cov=Lf @ cov_n[f] @ Lf.T))
    return out


def _centre(C: Array) -> Array:
    """Return the centre (2,) of the conic C: the solution of C[:2, :2] c = -C[:2, 2] (Cramer's
    rule in plain floats: numpy's solve costs tens of calls on a 2 x 2 system)."""
    (a, b, d), (_, c, e), _ = C.tolist()
    det = a * c - b * b
    return np.array([(b * e - c * d) / det, (b * d - a * e) / det])


def conic_points(C: Array, angles: Array) -> Array:
    """Return points (N, 2) of the ellipse C (3, 3) at parametric angles (N,) radians, measured
    along its axes (x^T C x = 0 at each)."""
    (a, b, d), (_, e, f), (_, _, g) = C.tolist()
    cx, cy = _centre(C).tolist()
    # The conic's value at the centre, in plain floats (numpy's products cost more calls than
    # the arithmetic on a 3 x 3 matrix): the axes' lengths scale by it.
    k = -(cx * (a * cx + b * cy + d) + cy * (b * cx + e * cy + f) + (d * cx + f * cy + g))
    w, V = np.linalg.eigh(C[:2, :2] / k)
    ax = 1.0 / np.sqrt(w)
    unit = np.empty((len(angles), 2))
    np.multiply(np.cos(angles), ax[0], out=unit[:, 0])
    np.multiply(np.sin(angles), ax[1], out=unit[:, 1])
    return unit @ V.T + [cx, cy]


def _conic_at_centre(C: Array) -> float:
    x = np.array([*_centre(C), 1.0])
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


def circle_distance(
    Q: ArrayLike, n: ArrayLike, m: ArrayLike, radius: float | Array
) -> Array | float:
    """Return the depth factor t (..., the circle's centre is t m) of a circle of `radius` (one,
    or one per conic (...)) with plane normal n (..., 3) whose centre's ray is m (..., 3, with
    m[2] = 1), from its cone Q (..., 3, 3); a float for single inputs.

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
