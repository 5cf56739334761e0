"""Homography estimation against cv2.findHomography(method=0): speed and accuracy.

Run from the repository root: python -m bench.bench_homography [n ...]
A plane-induced homography between two 640 x 480 views, n correspondences (default: 50, 1000
and 10000, one table each) with Gaussian noise sigma = 0.5 px in both images. Time: best of N
calls on one data set, the estimators interleaved round by round in one process so that the
ratios to cv2.findHomography(method=0) share the machine's load. Accuracy: RMS transfer error of
the estimate against the true H over a 20 x 15 grid of image points, pooled over independent
noise draws (200, or 20 at n > 2000; the error that matters downstream, in pixels), and the
efficiency against the Cramer-Rao bound (mean Mahalanobis error in the bound's metric / 8; 1.0
is the bound; n <= 1500).

BLAS: OpenBLAS reads OPENBLAS_CORETYPE and OPENBLAS_L2_SIZE, which some machines set and which
slow a current numpy; the first line printed says which are set and which kernel runs. To
measure without them, unset both in the bench command alone, e.g.
`env -u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE python -m bench.bench_homography`.
"""

from __future__ import annotations

import sys

import cv2
import numpy as np

from bench._common import best_of, print_table
from core.homography import fit_homography

# Plane-induced homography with strong perspective (local scale varies ~10x over the image):
# noise from the first image is far from uniform in the second, where the ML estimate matters.
H_TRUE = np.array([[2.0, 0.2, 60.0], [0.1, 2.2, 20.0], [6e-3, 2e-3, 1.0]])
SIGMA = 0.5


def project(H: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Return pi(H x) for points x (N, 2)."""
    p = x @ H[:, :2].T + H[:, 2]
    return p[:, :2] / p[:, 2:]


def scene(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Return the true first-image points (n, 2) and their images under H_TRUE."""
    x = rng.uniform([20.0, 20.0], [620.0, 460.0], size=(n, 2))
    return x, project(H_TRUE, x)


def crb(x: np.ndarray, sigma: float) -> np.ndarray:
    """Return the Cramer-Rao bound (8 x 8) on the free entries of H (H[2,2] = 1) for
    errors in both images: H's block of the inverse Fisher information (parameters H and the
    true points; central differences), i.e. the inverse of its Schur complement."""
    n = len(x)
    h = H_TRUE.ravel()[:8]
    eps = 1e-7
    jac = np.zeros((4 * n, 8 + 2 * n))

    def pred(hv: np.ndarray, pts: np.ndarray) -> np.ndarray:
        Hm = np.append(hv, 1.0).reshape(3, 3)
        return np.concatenate([pts.ravel(), project(Hm, pts).ravel()])

    theta = np.concatenate([h, x.ravel()])
    for k in range(len(theta)):
        step = eps * max(1.0, abs(theta[k]))
        tp, tm = theta.copy(), theta.copy()
        tp[k] += step
        tm[k] -= step
        jac[:, k] = (pred(tp[:8], tp[8:].reshape(-1, 2)) - pred(tm[:8], tm[8:].reshape(-1, 2))) / (
            2 * step
        )
    scale = np.linalg.norm(jac, axis=0)  # H's entries span 1e-3 .. 1e2
    js = jac / scale
    cov = np.linalg.inv(js.T @ js) / np.outer(scale, scale)
    return sigma**2 * cov[:8, :8]


def blas_line() -> str:
    """Return which OpenBLAS settings are in the environment and which kernel numpy runs."""
    import os

    env = {k: os.environ[k] for k in ("OPENBLAS_CORETYPE", "OPENBLAS_L2_SIZE") if k in os.environ}
    try:
        from threadpoolctl import threadpool_info

        kernels = [
            f"{i.get('internal_api')} {i.get('architecture')} x{i.get('num_threads')}"
            for i in threadpool_info()
            if i.get("user_api") == "blas"
        ]
    except ImportError:
        kernels = ["(threadpoolctl not installed)"]
    return f"BLAS: {', '.join(kernels)}; environment: {env or 'no OPENBLAS_CORETYPE/L2_SIZE'}"


def main(n: int) -> None:
    rng = np.random.default_rng(7)
    x, y = scene(n, rng)
    grid = np.stack(np.meshgrid(np.linspace(20, 620, 20), np.linspace(20, 460, 15)), -1)
    grid = grid.reshape(-1, 2)
    truth_grid = project(H_TRUE, grid)

    def estimators(src: np.ndarray, dst: np.ndarray) -> dict[str, np.ndarray]:
        return {
            "cv2.findHomography(0)": cv2.findHomography(src, dst, 0)[0],
            "dlt": fit_homography(src, dst, method="dlt").H,
            "transfer": fit_homography(src, dst, method="transfer").H,
            "gold": fit_homography(src, dst, method="gold").H,
        }

    # Timing first, in the fresh process (the accuracy loop's large allocations would leave
    # the allocator in a different state), interleaving the estimators round by round.
    src = x + rng.normal(0.0, SIGMA, x.shape)
    dst = y + rng.normal(0.0, SIGMA, y.shape)
    repeats = 200 if n <= 2000 else 30
    calls = {
        "cv2.findHomography(0)": lambda: cv2.findHomography(src, dst, 0),
        "dlt": lambda: fit_homography(src, dst, method="dlt"),
        "transfer": lambda: fit_homography(src, dst, method="transfer"),
        "gold": lambda: fit_homography(src, dst, method="gold"),
    }
    times = dict.fromkeys(calls, float("inf"))
    for _ in range(5):
        for name, fn in calls.items():
            times[name] = min(times[name], best_of(fn, repeats // 5))

    trials = 200 if n <= 2000 else 20
    sq = {k: 0.0 for k in estimators(x, y)}
    maha = dict.fromkeys(sq, 0.0)
    bound_inv = np.linalg.inv(crb(x, SIGMA)) if n <= 1500 else None
    for _ in range(trials):
        src = x + rng.normal(0.0, SIGMA, x.shape)
        dst = y + rng.normal(0.0, SIGMA, y.shape)
        for name, H in estimators(src, dst).items():
            H = H / H[2, 2]
            sq[name] += float(np.mean(np.sum((project(H, grid) - truth_grid) ** 2, axis=1)))
            if bound_inv is not None:
                e = (H - H_TRUE).ravel()[:8]
                maha[name] += float(e @ bound_inv @ e) / 8.0

    rows = []
    for name in calls:
        extra = {"grid RMS (px)": f"{np.sqrt(sq[name] / trials):.5f}"}
        if bound_inv is not None:
            extra["error / CRB"] = f"{maha[name] / trials:.3f}"
        rows.append((name, times[name], extra))
    print_table(
        f"Homography, n = {n}, sigma = {SIGMA} px in both images, {trials} noise draws",
        rows,
        anchor="cv2.findHomography(0)",
    )


def robust(n: int, outlier_ratio: float = 0.3) -> None:
    """Second table: LO-RANSAC against OpenCV's RANSAC and USAC (MAGSAC) with outliers."""
    rng = np.random.default_rng(11)
    x, y = scene(n, rng)
    src = x + rng.normal(0.0, SIGMA, x.shape)
    dst = y + rng.normal(0.0, SIGMA, y.shape)
    bad = rng.random(n) < outlier_ratio
    dst[bad] += rng.uniform(20.0, 200.0, (int(bad.sum()), 1)) * np.array([[0.6, 0.8]])
    grid = np.stack(np.meshgrid(np.linspace(20, 620, 20), np.linspace(20, 460, 15)), -1)
    grid = grid.reshape(-1, 2)
    truth_grid = project(H_TRUE, grid)

    def cv(flag: int) -> tuple[np.ndarray, np.ndarray]:
        H, mask = cv2.findHomography(src, dst, flag, 3.0, maxIters=5000, confidence=0.999)
        return H, mask.ravel().astype(bool)

    def ours(method: str) -> tuple[np.ndarray, np.ndarray]:
        fit = fit_homography(src, dst, method=method, robust=True, seed=0)  # type: ignore[call-overload]
        return fit.H, fit.inliers

    calls = {
        "cv2 RANSAC": lambda: cv(cv2.RANSAC),
        "cv2 USAC_MAGSAC": lambda: cv(cv2.USAC_MAGSAC),
        "LO-RANSAC + transfer": lambda: ours("transfer"),
        "LO-RANSAC + gold": lambda: ours("gold"),
    }
    rows = []
    for name, fn in calls.items():
        H, mask = fn()
        H = H / H[2, 2]
        err = np.sqrt(np.mean(np.sum((project(H, grid) - truth_grid) ** 2, axis=1)))
        extra = {
            "grid RMS (px)": f"{err:.4f}",
            "inliers found": f"{np.count_nonzero(mask & ~bad)}/{np.count_nonzero(~bad)}",
            "outliers kept": str(np.count_nonzero(mask & bad)),
        }
        rows.append((name, best_of(fn, 20), extra))
    print_table(
        f"Robust, n = {n}, {outlier_ratio:.0%} outliers (20-200 px off), threshold 3 px",
        rows,
        anchor="cv2 RANSAC",
    )


if __name__ == "__main__":
    print(blas_line())
    print()
    sizes = [int(a) for a in sys.argv[1:]] or [50, 1000, 10000]
    for size in sizes:
        main(size)
        print()
    robust(1000 if 1000 in sizes else sizes[0])
