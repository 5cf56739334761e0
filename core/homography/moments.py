"""Image moments of a region and the affine homography between two views of it (spec 01 §4).

Moments. For a region with density rho (a binary mask, a grey image, a filled polygon, or unit
masses at points) the raw moments are m_pq = sum x^p y^q rho(x, y) (an integral for a polygon),
the central moments mu_pq are the same about the centroid c = (m10, m01) / m00, and the
normalised central moments are nu_pq = mu_pq / m00^(1 + (p + q) / 2) (Hu 1962), as in
cv2.moments. Pixel coordinates: x is the column, y the row, and a pixel's centre is at integer
coordinates (OpenCV's convention).

Moments in homogeneous coordinates. With the homogeneous image point x~ = (x, y, 1), the moment
tensors M^(k) = sum x~ (x) ... (x) x~ (k factors) rho hold every raw moment of order <= k: e.g.
M^(2) = [[m20, m11, m10], [m11, m02, m01], [m10, m01, m00]], and M^(3)[i, j, k] = m_pq with p
the number of indices equal to 0 and q the number equal to 1. An affine map x~' = T x~,
T = [[A, b], [0, 0, 1]], transforms them linearly,

    M'^(k) = |det A|^s  T (x) ... (x) T  M^(k)         (s = 1 for a density, 0 for point masses)

and the same holds for moments taken in homogeneous projective (normalised camera) coordinates
m = K^-1 x~: K^-1 is such an affine T (its last row is (0, 0, 1)), so moments of a region in
normalised coordinates follow from its pixel moments with T = K^-1, and conversely. A general
homography x~' ~ H x~ does not act linearly on the tensors: the point is rescaled by
w(x) = h3^T x~ and the density by |det H| / w^3, so M'^(k) = |det H| sum (H x~)^(x)k w^-(k+3) rho
involves moments of every order. Moments are therefore affine-covariant only, and the affine
map recovered from them deviates from a perspective warp by an amount that grows with the
perspective terms h31, h32 times the region's extent (measured in bench/bench_moments.py).

Affine rules used below (x' = A x + b): m00' = |det A| m00 (m00 for point masses); the centroid
maps by (A, b); M2 = mu2 / m00, the covariance, maps as M2' = A M2 A^T; the third-order central
tensor M3 = mu3 / m00 as a symmetric 3-tensor, M3'_ijk = A_il A_jm A_kn M3_lmn; generally each
order of central moments as a symmetric tensor of that order.

Affine from moments (Sprinzak & Werman 1994; Heikkila 2004). Whitening by M2^-1/2 maps both
regions to unit covariance, leaving x_w' = Q x_w with Q orthogonal, so
A = M2b^1/2 Q M2a^-1/2 and b = cb - A ca. Q is the rotation (a reflection too when allowed) that
best aligns the whitened third-order tensors in the Frobenius norm. In complex notation
z = x + i y, the whitened tensor is carried by c30 = E[z^3] and c21 = E[z^2 conj z], a rotation
by theta multiplies them by e^(3 i theta) and e^(i theta), and

    <Q Ta, Tb>_F = Re(e^(3 i theta) c30a conj(c30b)) / 4 + 3 Re(e^(i theta) c21a conj(c21b)) / 4,

a trigonometric polynomial maximised exactly. Centrally symmetric shapes (disc, ellipse,
rectangle, any parallelogram) have no third-order information; a shape whose whitened version
has a 3-fold symmetry (every triangle) leaves Q ambiguous by 120 degrees: both are reported as
DegenerateConfiguration.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_matrix, as_points
from core.errors import DegenerateConfiguration, InvalidInput

Array = NDArray[np.float64]

DEFAULT_ORDER: Final = 3
# Whitened third-order tensors with a Frobenius norm below this carry no usable orientation:
# a pixelised, affinely warped disc, ellipse or rectangle of ~100 px leaves <= 3e-3, letter
# shapes (F, L) give 1.0 to 1.3 and a triangle 1.1.
DEFAULT_MIN_SKEWNESS: Final = 0.05
# Relative height gap between the best and the second-best alignment below which Q is
# ambiguous: a pixelised triangle gives ~1e-6, the letters F and L 0.14 to 0.16.
DEFAULT_MIN_MARGIN: Final = 0.05


def _readonly(a: Array) -> Array:
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class Moments:
    """Raw, central and normalised central moments of a region, up to `order`.

    raw[p, q] = m_pq, central[p, q] = mu_pq, normalized[p, q] = nu_pq, each (order+1, order+1),
    NaN where p + q > order. Units: pixels^(p+q) times the density (1 per pixel or unit area for
    masks and polygons, the grey level for images, 1 per point for point sets).
    is_area: True for densities (mask, image, polygon), whose mass scales by |det A| under an
    affine map; False for point masses.
    """

    raw: Array
    central: Array
    normalized: Array
    is_area: bool

    @property
    def order(self) -> int:
        """Return the highest order p + q held."""
        return int(self.raw.shape[0] - 1)

    @property
    def m00(self) -> float:
        """Return the mass: area in px^2, total grey level, or number of points."""
        return float(self.raw[0, 0])

    @property
    def centroid(self) -> Array:
        """Return the centroid (x, y), shape (2,), pixels."""
        return np.array([self.raw[1, 0], self.raw[0, 1]]) / self.raw[0, 0]

    @property
    def mu2(self) -> Array:
        """Return the second-order central moments [[mu20, mu11], [mu11, mu02]], shape (2, 2)."""
        c = self.central
        return np.array([[c[2, 0], c[1, 1]], [c[1, 1], c[0, 2]]])

    @property
    def mu3(self) -> Array:
        """Return the third-order central moment tensor T[i, j, k] = mu_pq, shape (2, 2, 2).

        p is the number of indices equal to 0 (x) and q the number equal to 1 (y); its four
        unique values are mu30, mu21, mu12, mu03.
        """
        return _tensor_from_moments(self.central, 3)

    @property
    def cov(self) -> Array:
        """Return M2 = mu2 / m00, the covariance of the region, shape (2, 2), pixels^2."""
        return self.mu2 / self.m00

    @property
    def skew3(self) -> Array:
        """Return M3 = mu3 / m00, the third-order central tensor per unit mass, (2, 2, 2)."""
        return self.mu3 / self.m00

    def as_cv_dict(self) -> dict[str, float]:
        """Return the moments keyed as cv2.moments does (m00 ... m03, mu20 ..., nu20 ...)."""
        out: dict[str, float] = {}
        for k in range(min(self.order, 3) + 1):
            for q in range(k + 1):
                p = k - q
                out[f"m{p}{q}"] = float(self.raw[p, q])
                if k >= 2:
                    out[f"mu{p}{q}"] = float(self.central[p, q])
                    out[f"nu{p}{q}"] = float(self.normalized[p, q])
        return out


def _tensor_from_moments(mom: Array, k: int) -> Array:
    """Return the symmetric (2,)*k tensor T[i...] = mom[p, q], p = #zeros, q = #ones."""
    if mom.shape[0] <= k:
        raise InvalidInput(f"moments of order {k} were not computed (order {mom.shape[0] - 1})")
    T = np.empty((2,) * k)
    for idx in np.ndindex(*T.shape):
        q = sum(idx)
        T[idx] = mom[k - q, q]
    return T


def _mask_out(a: Array, order: int) -> Array:
    p, q = np.indices(a.shape)
    a[p + q > order] = np.nan
    return a


def _normalized(central: Array, m00: float) -> Array:
    p, q = np.indices(central.shape)
    with np.errstate(invalid="ignore"):
        return central / m00 ** (1.0 + (p + q) / 2.0)


def _shift(mom: Array, dx: float, dy: float) -> Array:
    """Return moments in coordinates shifted by (dx, dy): m'_pq = sum m_ij of (x+dx)^p (y+dy)^q.

    m'_pq = sum_{i<=p, j<=q} C(p, i) C(q, j) dx^(p-i) dy^(q-j) m_ij (binomial theorem).
    """
    n = mom.shape[0]
    Bx = np.zeros((n, n))
    By = np.zeros((n, n))
    for p in range(n):
        for i in range(p + 1):
            Bx[p, i] = comb(p, i) * dx ** (p - i)
            By[p, i] = comb(p, i) * dy ** (p - i)
    m = np.nan_to_num(mom, nan=0.0)
    return Bx @ m @ By.T


def _finish(about: Array, origin: Array, order: int, is_area: bool) -> Moments:
    """Build Moments from moments `about` taken about `origin` (each (order+1, order+1))."""
    m00 = float(about[0, 0])
    if not m00 > 0:
        raise DegenerateConfiguration(
            "the region has no mass (empty mask, zero image or zero-area polygon); "
            "pass a region that covers some pixels"
        )
    off = np.array([about[1, 0], about[0, 1]]) / m00  # centroid - origin
    central = _mask_out(_shift(about, -off[0], -off[1]), order)
    central[1, 0] = central[0, 1] = 0.0  # exactly, by definition of the centroid
    raw = _mask_out(_shift(about, origin[0], origin[1]), order)
    return Moments(
        raw=_readonly(raw),
        central=_readonly(central),
        normalized=_readonly(_mask_out(_normalized(central, m00), order)),
        is_area=is_area,
    )


def _check_order(order: int) -> None:
    if not isinstance(order, int | np.integer) or order < 0:
        raise InvalidInput(f"order must be a non-negative integer, got {order!r}")


def _as_image(image: ArrayLike, name: str) -> Array:
    try:
        a = np.asarray(image)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"{name} must be a 2-D numeric array: {exc}") from None
    if a.ndim != 2 or a.size == 0:
        raise InvalidInput(f"{name} must be a non-empty 2-D array (rows, cols), got {a.shape}")
    if not (np.issubdtype(a.dtype, np.number) or a.dtype == np.bool_):
        raise InvalidInput(f"{name} must be numeric or boolean, got dtype {a.dtype}")
    f = a.astype(np.float64)
    if not np.all(np.isfinite(f)):
        raise InvalidInput(f"{name} contains NaN or infinite values")
    return f


def _grid_moments(img: Array, order: int) -> Moments:
    """Moments of a density sampled on the pixel grid (pixel centres at integer coordinates)."""
    rows, cols = img.shape
    m00 = float(img.sum())
    if not m00 > 0:
        raise DegenerateConfiguration(
            "the region is empty (no nonzero pixel, or grey levels summing to <= 0); "
            "check the segmentation"
        )
    x = np.arange(cols, dtype=np.float64)
    y = np.arange(rows, dtype=np.float64)
    # Moments about the centroid directly (not from the raw ones), which avoids the cancellation
    # of raw -> central at large coordinates; the raw moments then follow by the binomial shift.
    cx = float(img.sum(axis=0) @ x) / m00
    cy = float(img.sum(axis=1) @ y) / m00
    powers = np.arange(order + 1)
    X = (x - cx)[:, None] ** powers  # (cols, order+1)
    Y = (y - cy)[:, None] ** powers  # (rows, order+1)
    about = (img @ X).T @ Y  # about[p, q] = sum (x - cx)^p (y - cy)^q img
    return _finish(about, np.array([cx, cy]), order, is_area=True)


def mask_moments(mask: ArrayLike, order: int = DEFAULT_ORDER) -> Moments:
    """Return the moments of a binary mask (nonzero = inside), equal to cv2.moments(mask, True).

    mask: (rows, cols) bool or numeric array. Raises InvalidInput (not 2-D, NaN) or
    DegenerateConfiguration (empty mask).
    """
    _check_order(order)
    img = _as_image(mask, "mask")
    return _grid_moments((img != 0).astype(np.float64), order)


def image_moments(image: ArrayLike, order: int = DEFAULT_ORDER) -> Moments:
    """Return the moments of a grey image (intensity-weighted), equal to cv2.moments(image).

    image: (rows, cols) numeric array. Raises InvalidInput (not 2-D, NaN) or
    DegenerateConfiguration (total intensity <= 0).
    """
    _check_order(order)
    return _grid_moments(_as_image(image, "image"), order)


def polygon_moments(vertices: ArrayLike, order: int = DEFAULT_ORDER) -> Moments:
    """Return the moments of the filled polygon, in closed form by Green's theorem.

    vertices: (N, 2) polygon vertices in order (either orientation), N >= 3, pixels; the
    polygon is closed implicitly. Uses (Steger 1996, "On the calculation of arbitrary moments
    of polygons", TU Munich report FGBV-96-05)

        m_pq = 1 / ((p+q+2)(p+q+1) C(p+q, p)) sum_i (x_{i-1} y_i - x_i y_{i-1})
               sum_{k<=p} sum_{l<=q} C(k+l, l) C(p+q-k-l, q-l)
                                     x_i^k x_{i-1}^(p-k) y_i^l y_{i-1}^(q-l)

    evaluated about the vertex mean (for precision) and shifted. The sign is that of a positive
    area whatever the orientation, as in cv2.moments. Raises InvalidInput, NotEnoughPoints or
    DegenerateConfiguration (zero area).
    """
    _check_order(order)
    v = as_points(vertices, 2, "vertices", min_count=3)
    origin = v.mean(axis=0)
    u = v - origin
    x1, y1 = u[:, 0], u[:, 1]
    x0, y0 = np.roll(x1, 1), np.roll(y1, 1)
    cross = x0 * y1 - x1 * y0
    about = np.zeros((order + 1, order + 1))
    for p in range(order + 1):
        for q in range(order + 1 - p):
            acc = np.zeros_like(cross)
            for k in range(p + 1):
                for l in range(q + 1):
                    acc += (
                        comb(k + l, l)
                        * comb(p + q - k - l, q - l)
                        * x1**k
                        * x0 ** (p - k)
                        * y1**l
                        * y0 ** (q - l)
                    )
            about[p, q] = (cross @ acc) / ((p + q + 2) * (p + q + 1) * comb(p + q, p))
    scale = float(np.abs(u).max())
    if abs(about[0, 0]) <= 1e-14 * scale * scale * len(v):
        raise DegenerateConfiguration(
            "the polygon has zero area (collinear or repeated vertices); pass a simple polygon"
        )
    if about[0, 0] < 0:
        about = -about
    return _finish(about, origin, order, is_area=True)


def point_moments(
    points: ArrayLike, order: int = DEFAULT_ORDER, weights: ArrayLike | None = None
) -> Moments:
    """Return the moments of a point set (unit masses, or `weights` (N,) > 0 per point).

    points: (N, 2), N >= 1. Raises InvalidInput or DegenerateConfiguration (zero total weight).
    """
    _check_order(order)
    P = as_points(points, 2, "points", min_count=1)
    if weights is None:
        w = np.ones(len(P))
    else:
        w = np.asarray(weights, dtype=np.float64)
        if w.shape != (len(P),) or not np.all(np.isfinite(w)) or np.any(w < 0):
            raise InvalidInput(f"weights must be {len(P)} finite values >= 0, got shape {w.shape}")
    m00 = float(w.sum())
    if not m00 > 0:
        raise DegenerateConfiguration("the point weights sum to zero; give some point a weight")
    c = (w @ P) / m00
    powers = np.arange(order + 1)
    X = (P[:, 0] - c[0])[:, None] ** powers
    Y = (P[:, 1] - c[1])[:, None] ** powers
    about = (X * w[:, None]).T @ Y
    return _finish(about, c, order, is_area=False)


def _linear_form_power(a: float, b: float, k: int) -> Array:
    """Return coefficients c[i] of (a x + b y)^k = sum_i c[i] x^i y^(k-i), shape (k+1,)."""
    out = np.array([1.0])
    for _ in range(k):
        out = np.convolve(out, [b, a])  # index = power of x
    return out


def transform_moments(mom: Moments, A: ArrayLike, b: ArrayLike) -> Moments:
    """Return the moments of the region mapped by x' = A x + b (exact, every order held).

    A: (2, 2) non-singular, b: (2,). The centroid maps by (A, b); the central moments of order
    k transform as a symmetric k-tensor, mu'_pq = f sum_ij c_ij mu_ij with (A x)_1^p (A x)_2^q =
    sum c_ij x^i y^j, and f = |det A| for densities (area scales), 1 for point masses; so
    M2' = A M2 A^T and M3' = A (x) A (x) A M3 per unit mass. Raises DegenerateConfiguration for
    a singular A.
    """
    Am = as_matrix(A, (2, 2), "A")
    bv = as_matrix(b, (2,), "b")
    det = float(np.linalg.det(Am))
    if abs(det) <= 1e-12 * max(float(np.abs(Am).max()), 1e-300) ** 2:
        raise DegenerateConfiguration("A is singular; an affine map must be invertible")
    f = abs(det) if mom.is_area else 1.0
    order = mom.order
    central = np.full((order + 1, order + 1), np.nan)
    for k in range(order + 1):
        for q in range(k + 1):
            p = k - q
            poly = np.convolve(
                _linear_form_power(Am[0, 0], Am[0, 1], p), _linear_form_power(Am[1, 0], Am[1, 1], q)
            )
            central[p, q] = f * sum(poly[i] * mom.central[i, k - i] for i in range(k + 1))
    m00 = f * mom.m00
    c = Am @ mom.centroid + bv
    central[1, 0] = central[0, 1] = 0.0
    raw = _mask_out(_shift(central, c[0], c[1]), order)
    return Moments(
        raw=_readonly(raw),
        central=_readonly(central),
        normalized=_readonly(_mask_out(_normalized(central, m00), order)),
        is_area=mom.is_area,
    )


def homogeneous_moments(mom: Moments) -> tuple[Array, Array]:
    """Return the raw moment tensors in homogeneous coordinates, (3, 3) and (3, 3, 3).

    M2[i, j] = sum x~_i x~_j rho and M3[i, j, k] = sum x~_i x~_j x~_k rho with x~ = (x, y, 1);
    under x~' = T x~ they map as |det A|^s T M2 T^T and T (x) T (x) T M3 (module docstring).
    Requires order >= 3.
    """
    if mom.order < 3:
        raise InvalidInput(f"homogeneous_moments needs moments up to order 3, got {mom.order}")

    def tensor(k: int) -> Array:
        T = np.empty((3,) * k)
        for idx in np.ndindex(*T.shape):
            p = sum(1 for i in idx if i == 0)
            q = sum(1 for i in idx if i == 1)
            T[idx] = mom.raw[p, q]
        return T

    return tensor(2), tensor(3)


@dataclass(frozen=True)
class MomentAffine:
    """An affine map x_b = A x_a + b estimated from the moments of two regions, with diagnostics.

    A: (2, 2); b: (2,) pixels; Q: (2, 2) the orthogonal map between the whitened regions.
    skewness: Frobenius norms of the two whitened third-order tensors (0 = no orientation).
    margin: relative gap in [0, 1] between the best alignment of the third-order tensors and
    the runner-up (0 = ambiguous, e.g. a triangle).
    misfit: ||Tb - Q Ta||_F / ||Tb||_F after alignment (0 for an exact affine relation;
    pixelised letters of ~100 px give 1e-3 to 3e-2, perspective more).
    """

    A: Array
    b: Array
    Q: Array
    skewness: tuple[float, float]
    margin: float
    misfit: float

    @property
    def matrix(self) -> Array:
        """Return [A | b], shape (2, 3), so that matrix @ (x, y, 1) maps a point of a to b."""
        return np.hstack([self.A, self.b[:, None]])


def _sqrtm_spd(C: Array, name: str) -> tuple[Array, Array]:
    """Return (C^1/2, C^-1/2) of a symmetric positive definite 2x2 matrix."""
    w, V = np.linalg.eigh(C)
    if not w[0] > 1e-12 * max(w[1], 1e-300):
        raise DegenerateConfiguration(
            f"region {name} has no extent in one direction (a line or a point); "
            "an affine map needs a region with area"
        )
    s = np.sqrt(w)
    return (V * s) @ V.T, (V / s) @ V.T


def _complex_third(T: Array) -> tuple[complex, complex]:
    """Return (c30, c21) = (E[z^3], E[z^2 conj z]) of a symmetric 2x2x2 tensor, z = x + i y."""
    xxx, xxy, xyy, yyy = T[0, 0, 0], T[0, 0, 1], T[0, 1, 1], T[1, 1, 1]
    c30 = complex(xxx - 3 * xyy, 3 * xxy - yyy)
    c21 = complex(xxx + xyy, xxy + yyy)
    return c30, c21


def _apply3(M: Array, T: Array) -> Array:
    return np.einsum("il,jm,kn,lmn->ijk", M, M, M, T)


def _best_rotation(a3: complex, a1: complex) -> list[tuple[float, float]]:
    """Return the local maxima (theta, value) of f = Re(a3 e^(3 i theta) + a1 e^(i theta)).

    Sampled every 0.5 degree (f has at most three maxima, separated by more than that), then
    polished by Newton's method on f' = 0.
    """
    theta = np.linspace(0.0, 2 * np.pi, 720, endpoint=False)
    z = np.exp(1j * theta)
    f = np.real(a3 * z**3 + a1 * z)
    peaks = np.nonzero((f >= np.roll(f, 1)) & (f > np.roll(f, -1)))[0]
    out = []
    for i in peaks:
        th = float(theta[i])
        for _ in range(8):
            e1, e3 = np.exp(1j * th), np.exp(3j * th)
            d1 = -np.imag(3 * a3 * e3 + a1 * e1)
            d2 = -np.real(9 * a3 * e3 + a1 * e1)
            if d2 >= 0:
                break
            th -= d1 / d2
        val = float(np.real(a3 * np.exp(3j * th) + a1 * np.exp(1j * th)))
        out.append((th, val) if val >= f[i] else (float(theta[i]), float(f[i])))
    return out


def estimate_affine_from_moments(
    moments_a: Moments,
    moments_b: Moments,
    *,
    allow_reflection: bool = False,
    min_skewness: float = DEFAULT_MIN_SKEWNESS,
    min_margin: float = DEFAULT_MIN_MARGIN,
) -> MomentAffine:
    """Return the affine map taking region a to region b estimated from their moments alone.

    moments_a, moments_b: Moments up to order >= 3 of the two regions (masks, images, polygons
    or point sets). Whitening by M2^-1/2 and aligning the whitened third-order tensors (module
    docstring): A = M2b^1/2 Q M2a^-1/2, b = cb - A ca, with det A > 0 unless allow_reflection.
    Exact for regions that are exact affine images of each other (point sets, polygons);
    pixelised masks agree to discretisation error.

    Raises InvalidInput (order < 3), DegenerateConfiguration when a region has no third-order
    information (whitened skewness < min_skewness: centrally symmetric shapes such as a disc,
    an ellipse or a rectangle) or when the alignment is ambiguous (margin < min_margin, e.g.
    a triangle, affinely 3-fold symmetric).
    """
    for name, m in (("a", moments_a), ("b", moments_b)):
        if m.order < 3:
            raise InvalidInput(f"moments of region {name} must go up to order 3, got {m.order}")
    _, Wa = _sqrtm_spd(moments_a.cov, "a")
    Sb, Wb = _sqrtm_spd(moments_b.cov, "b")
    Ta = _apply3(Wa, moments_a.skew3)
    Tb = _apply3(Wb, moments_b.skew3)
    ska, skb = float(np.linalg.norm(Ta)), float(np.linalg.norm(Tb))
    if min(ska, skb) < min_skewness:
        which = "a" if ska < skb else "b"
        raise DegenerateConfiguration(
            f"region {which} has no third-order moment information (whitened skewness "
            f"{min(ska, skb):.2g} < {min_skewness}): it is centrally symmetric, like a disc, an "
            "ellipse or a rectangle, so its orientation cannot be recovered from moments; use "
            "point correspondences or an asymmetric marker"
        )
    c30a, c21a = _complex_third(Ta)
    c30b, c21b = _complex_third(Tb)

    # Rotations Q = R(theta), and with reflection R(theta) diag(1, -1) (conjugates a's moments).
    flips = [False, True] if allow_reflection else [False]
    peaks: list[tuple[float, float, bool]] = []
    for flip in flips:
        p30, p21 = (np.conj(c30a), np.conj(c21a)) if flip else (c30a, c21a)
        a3 = p30 * np.conj(c30b) / 4.0
        a1 = 3.0 * p21 * np.conj(c21b) / 4.0
        peaks += [(th, v, flip) for th, v in _best_rotation(a3, a1)]
    if not peaks:  # f is constant: the two tensors are orthogonal, nothing to align
        peaks = [(0.0, 0.0, False)]
    peaks.sort(key=lambda pk: -pk[1])
    theta, best, flip = peaks[0]
    # f ranges over [-ska * skb, ska * skb] (Cauchy-Schwarz); the gap to the runner-up peak, or
    # to the minimum when the best is the only peak, relative to that range.
    span = 2.0 * ska * skb
    runner_up = peaks[1][1] if len(peaks) > 1 else -ska * skb
    margin = float(min(1.0, (best - runner_up) / span)) if span > 0 else 0.0
    if margin < min_margin:
        raise DegenerateConfiguration(
            f"the third-order moments leave the orientation ambiguous (margin {margin:.2g} < "
            f"{min_margin}): the region is affinely symmetric (e.g. a triangle), so several "
            "affine maps fit equally; use point correspondences or an asymmetric marker"
        )
    c, s = np.cos(theta), np.sin(theta)
    Q = np.array([[c, -s], [s, c]])
    if flip:
        Q = Q @ np.diag([1.0, -1.0])
    A = Sb @ Q @ Wa
    b = moments_b.centroid - A @ moments_a.centroid
    misfit = float(np.linalg.norm(Tb - _apply3(Q, Ta)) / skb)
    return MomentAffine(A=A, b=b, Q=Q, skewness=(ska, skb), margin=margin, misfit=misfit)


def affine_from_moments(
    region_a: ArrayLike, region_b: ArrayLike, *, allow_reflection: bool = False
) -> Array:
    """Return the 2x3 affine map [A | b] taking region a to region b, from image moments only.

    region_a, region_b: binary masks (bool or uint8, nonzero = inside) of equal shape; pixel
    coordinates (x = column, y = row). No point correspondences are needed; see
    estimate_affine_from_moments for the method and its diagnostics. det A > 0 unless
    allow_reflection. Raises InvalidInput (shapes differ, not 2-D) or DegenerateConfiguration
    (empty mask, centrally symmetric or affinely symmetric region).
    """
    a = np.asarray(region_a)
    b = np.asarray(region_b)
    if a.shape != b.shape:
        raise InvalidInput(
            f"region_a and region_b must be masks of equal shape, got {a.shape} and {b.shape}"
        )
    fit = estimate_affine_from_moments(
        mask_moments(a), mask_moments(b), allow_reflection=allow_reflection
    )
    return fit.matrix
