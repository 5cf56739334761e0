"""Homography estimation: normalised DLT, transfer-error LM, gold-standard ML, LO-RANSAC.

Two cases (spec 01, section 1):

* world-plane homography: src are exact metric plane coordinates, only dst is noisy; the ML
  estimate minimises the transfer error in dst (`method="transfer"`, H&Z eq. 4.6);
* plane-induced homography between two images: both sides are noisy; the ML estimate is the gold
  standard (`method="gold"`, H&Z alg. 4.3, eq. 4.8), solved by Gauss-Newton with the corrected
  first-image points eliminated by their Schur complement in closed form
  (`core.homography.gold`), handing over to the damped sparse LM (core.optim) when an undamped
  step fails.

Every iterative estimate runs in Hartley-normalised coordinates (H&Z alg. 4.2) with the gauge
H_n[2,2] = 1 and the residuals kept in the input units (pixels), then maps H and its covariance
back to the input coordinates with the gauge H[2,2] = 1.

The pieces live beside this module: the correspondences' checks and normalisation
(`core.homography.normalization`), the normalised DLT (`core.homography.dlt`), the sparse LM's
problems (`core.homography.problems`), the gold standard's closed-form solver
(`core.homography.gold`) and LO-RANSAC (`core.homography.ransac`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_points
from core.errors import InvalidInput
from core.homography.dlt import _dlt_normalized, _unit_h22
from core.homography.gold import _fit_gold
from core.homography.normalization import (
    _normalize_t,
    _pair_inputs,
    check_homography_configuration,
)
from core.homography.problems import _LM_PTOL, _h_from_params, _TransferProblem
from core.homography.ransac import _lo_ransac
from core.optim import solve_sparse_lm

Array = NDArray[np.float64]
Method = Literal["gold", "transfer", "dlt"]


@dataclass(frozen=True)
class HomographyFit:
    """A fitted homography dst ~ H src with its diagnostics.

    Attributes:
        H: (3, 3) homography in the input coordinates, H[2, 2] = 1.
        rms: root mean square of the residuals the method minimises, per coordinate, in the
            input units of the images (pixels): for "transfer" and "dlt",
            sqrt(sum_i ||x'_i - pi(H x_i)||^2 / (2 n)); for "gold",
            sqrt(sum_i (||x_i - x^_i||^2 + ||x'_i - pi(H x^_i)||^2) / (4 n)); n counts inliers.
            Under Gaussian noise sigma it tends to sigma sqrt(1 - 4/n) (transfer) and
            sigma sqrt((n - 4) / (2 n)) (gold): sigma sqrt(1 - d / N) for N measurements and d
            parameters (H&Z ch. 5, spec 01 sec. 1).
        cov: (9, 9) covariance of H's entries (row-major), gauge H[2,2] = 1 removed (zero row and
            column 8), scaled by the estimated residual variance 2 cost / (N - d): the inverse of
            the gauge-fixed Gauss-Newton information (H&Z ch. 5 and A6.4), propagated from the
            normalised coordinates.
            For "dlt" it is the transfer-error covariance evaluated at the DLT estimate
            (first-order; exact for the transfer estimator). NaN when n = 4 (no redundancy).
        inliers: (N,) bool mask of the correspondences used; all True without RANSAC.
        iterations: LM iterations of the refinement (0 for "dlt").
        method: the estimator that produced H.
        src_corrected: for "gold", (N, 2) the ML estimates x^_i of the first-image points
            (NaN rows for outliers); None otherwise.
        ransac_iterations: minimal samples drawn by RANSAC (0 without RANSAC).
    """

    H: Array
    rms: float
    cov: Array = field(repr=False)
    inliers: NDArray[np.bool_] = field(repr=False)
    iterations: int
    method: Method
    src_corrected: Array | None = field(default=None, repr=False)
    ransac_iterations: int = 0

    @property
    def n_inliers(self) -> int:
        """Number of correspondences used in the final fit."""
        return int(np.count_nonzero(self.inliers))


def _denormalize(g: Array, cov_g: Array, Ts: Array, Td: Array) -> tuple[Array, Array]:
    """Return (H, cov_H (9x9)) in input coordinates from H_n = H(g) with covariance cov_g.

    H = Td^-1 H_n Ts / (.)[2,2]; the covariance propagates by the Jacobian of that map (linear
    in H_n, then the gauge normalisation H[2,2] = 1), so row/column 8 come out zero.
    """
    (k, _, tx), (_, _, ty), _ = Td.tolist()  # Td = [[k, 0, tx], [0, k, ty], [0, 0, 1]]
    td_inv = np.array([[1.0 / k, 0.0, -tx / k], [0.0, 1.0 / k, -ty / k], [0.0, 0.0, 1.0]])
    h_raw = td_inv @ _h_from_params(g) @ Ts
    h = h_raw.ravel()
    h22 = float(h[8])
    H = _unit_h22(h_raw)
    # Row-major vec(A X B) = kron(A, B^T) vec(X); columns 0..7 are the free entries of H_n.
    m = (td_inv[:, None, :, None] * Ts.T[None, :, None, :]).reshape(9, 9)[:, :8]
    jac = m - h[:, None] * (m[8] / h22)
    jac *= 1.0 / h22
    cov = jac @ cov_g @ jac.T
    cov[8, :] = 0.0
    cov[:, 8] = 0.0
    cov += cov.T
    cov *= 0.5
    return H, cov


def fit_homography(
    src: ArrayLike,
    dst: ArrayLike,
    *,
    method: Method = "gold",
    robust: bool | Literal["ransac"] = False,
    ransac_threshold: float = 3.0,
    ransac_confidence: float = 0.999,
    ransac_max_iterations: int = 5000,
    seed: int | np.random.Generator | None = 0,
    max_iterations: int = 50,
) -> HomographyFit:
    """Return the HomographyFit of dst ~ H src by the chosen estimator.

    src, dst: (N, 2) corresponding points, N >= 4 (pixels; src may be metric plane coordinates).

    method:
        "dlt": normalised DLT (H&Z alg. 4.2), algebraic error.
        "transfer": LM on the dst transfer error sum ||x'_i - pi(H x_i)||^2 over the 8 dof of H
            (H&Z eq. 4.6); the ML estimate when src is exact (world-plane homography).
        "gold": gold-standard ML (H&Z alg. 4.3): minimises
            sum ||x_i - x^_i||^2 + ||x'_i - pi(H x^_i)||^2 (eq. 4.8) over H and the corrected
            points x^_i, by Gauss-Newton with the points eliminated in closed form (the sparse
            LM's Schur complement written out per point; the damped sparse LM takes over when a
            step fails); the ML estimate under equal isotropic Gaussian noise in both images
            (plane-induced homography).
        The iterative methods start from the DLT (and, for "gold", the Sampson points) and stop
        after `max_iterations`.
    robust: False, or True / "ransac" for LO-RANSAC (Chum, Matas & Kittler 2003) on 4-point
        minimal samples scored by the truncated dst transfer error (MSAC), with inliers at
        transfer error < `ransac_threshold` (input units of dst), refitting the DLT on the
        inliers of every new best model, and an adaptive sample count reaching
        `ransac_confidence`, capped at `ransac_max_iterations`; `seed` (int or Generator) makes
        it deterministic. The chosen method then runs on the inliers.

    Raises NotEnoughPoints (N < 4), InvalidInput (shape, NaN/inf, unknown option),
    DegenerateConfiguration (collinear points, no consensus, H[2,2] = 0).
    """
    s, d = _pair_inputs(src, dst)
    if method not in ("gold", "transfer", "dlt"):
        raise InvalidInput(f"method must be 'gold', 'transfer' or 'dlt', got {method!r}")
    if robust not in (False, True, "ransac"):
        raise InvalidInput(f"robust must be False, True or 'ransac', got {robust!r}")
    n = len(s)
    inliers = np.ones(n, dtype=bool)
    ransac_iterations = 0
    if robust:
        check_homography_configuration(s, d)
        if not (ransac_threshold > 0 and np.isfinite(ransac_threshold)):
            raise InvalidInput(f"ransac_threshold must be > 0, got {ransac_threshold}")
        if not 0 < ransac_confidence < 1:
            raise InvalidInput(f"ransac_confidence must be in (0, 1), got {ransac_confidence}")
        consensus = _lo_ransac(
            s,
            d,
            ransac_threshold,
            ransac_confidence,
            max(int(ransac_max_iterations), 1),
            np.random.default_rng(seed),
        )
        inliers, ransac_iterations = consensus.inliers, consensus.samples
        s, d = s[inliers], d[inliers]

    Ts, ps_t = _normalize_t(s, "src")
    Td, pd_t = _normalize_t(d, "dst")
    hn = _unit_h22(_dlt_normalized(ps_t, pd_t), "the normalised DLT estimate")
    g0 = hn.ravel()[:8]
    src_scale, dst_scale = float(Ts[0, 0]), float(Td[0, 0])

    m = ps_t.shape[1]
    corrected: Array | None = None
    if method == "gold":
        fit = _fit_gold(ps_t, pd_t, hn, src_scale, dst_scale, max_iterations)
        g, information, cost, iterations = fit.g, fit.information, fit.cost, fit.iterations
        inverse = fit.information_inverse
        n_residuals, n_parameters = 4 * m, 8 + 2 * m
        x_hat = ((fit.x_hat - Ts[:2, 2:]) / src_scale).T
        if robust:
            corrected = np.full((n, 2), np.nan)
            corrected[inliers] = x_hat
        else:
            corrected = x_hat
    else:
        lm = solve_sparse_lm(
            _TransferProblem(ps_t, pd_t, dst_scale),
            g0,
            np.zeros((m, 0)),
            max_iterations=0 if method == "dlt" else max_iterations,
            ptol=_LM_PTOL,
        )
        g, information, cost, iterations = lm.x_global, lm.information, lm.cost, lm.iterations
        inverse = None
        n_residuals, n_parameters = 2 * m, 8
    # Residual variance 2 cost / (N - d) (NaN without redundancy, n = 4).
    dof = n_residuals - n_parameters
    variance = 2.0 * cost / dof if dof > 0 else float("nan")
    # The gauge H_n[2,2] = 1 leaves no freedom, so S is invertible (pinv would cost 8x more).
    if inverse is not None:
        cov_g: Array = variance * inverse
    else:
        try:
            cov_g = variance * np.asarray(np.linalg.inv(information), np.float64)
        except np.linalg.LinAlgError:
            cov_g = variance * np.linalg.pinv(information, hermitian=True).astype(np.float64)
    H, cov = _denormalize(g, cov_g, Ts, Td)
    return HomographyFit(
        H=H,
        rms=float(np.sqrt(2.0 * cost / n_residuals)),
        cov=cov,
        inliers=inliers,
        iterations=iterations,
        method=method,
        src_corrected=corrected,
        ransac_iterations=ransac_iterations,
    )


def transfer_covariance(fit: HomographyFit, points: ArrayLike) -> Array:
    """Return the (N, 2, 2) covariance of pi(H x) for points x (N, 2) in src coordinates.

    First-order propagation of `fit.cov` (H&Z ch. 5): J cov J^T with J = d pi(H x) / d vec(H)
    (2 x 9). The points themselves are taken as exact; units are those of dst, squared.
    """
    x = as_points(points, 2, "points")
    ph = x @ fit.H[:, :2].T + fit.H[:, 2]
    inv_w = 1.0 / ph[:, 2]
    uv = ph[:, :2] * inv_w[:, None]
    xh = np.hstack([x, np.ones((len(x), 1))]) * inv_w[:, None]
    jac = np.zeros((len(x), 2, 9))
    jac[:, 0, 0:3] = xh
    jac[:, 1, 3:6] = xh
    jac[:, :, 6:9] = -uv[:, :, None] * xh[:, None, :]
    out: Array = jac @ fit.cov @ jac.transpose(0, 2, 1)
    return out
