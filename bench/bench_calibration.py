"""Benchmark: Zhang calibration (closed form + sparse-LM refinement) against cv2.calibrateCamera.

Run from the repository root: `python -m bench.bench_calibration`. Prints

* the time of `core.calibration.calibrate_camera` and of cv2.calibrateCamera (best of N, wall
  clock, time.perf_counter) on 20 views x 100 points with OpenCV's 5-coefficient distortion,
  with their RMS (they must agree to 1e-6 px: the same optimum) and the time ratio (target
  <= 1.5);
* a profile split of our call: closed form, Jacobian evaluation, LM linear algebra;
* Zhang's published real data (MSR 1998) against his published values.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import cv2
import numpy as np

from core.calibration import calibrate_camera, intrinsics_from_homographies, pose_from_homography
from core.geometry.camera import ReprojectionProblem, project_points
from core.homography import dlt_homography
from tests.support.zhang import DATA, PUBLISHED, decimals, read_zhang, zhang_values


def synthetic_views(
    n_views: int = 20, grid: tuple[int, int] = (10, 10), sigma: float = 0.3, seed: int = 0
) -> tuple[list[np.ndarray], list[np.ndarray], tuple[int, int]]:
    """Return float32-exact object points (N, 3), noisy pixels (N, 2) per view, image size."""
    rng = np.random.default_rng(seed)
    K = np.array([[1000.0, 0.0, 645.0], [0.0, 1005.0, 355.0], [0.0, 0.0, 1.0]])
    dist = np.array([-0.28, 0.12, 0.0008, -0.0005, -0.03])
    gx, gy = np.meshgrid(np.arange(grid[0]), np.arange(grid[1]))
    X = np.stack([gx.ravel() * 0.03, gy.ravel() * 0.03, np.zeros(gx.size)], 1)
    X -= [0.03 * (grid[0] - 1) / 2, 0.03 * (grid[1] - 1) / 2, 0.0]
    obj, img = [], []
    for _ in range(n_views):
        rvec = rng.normal(0.0, 0.35, 3)
        tvec = np.array(
            [rng.uniform(-0.08, 0.08), rng.uniform(-0.05, 0.05), rng.uniform(0.45, 0.8)]
        )
        uv = project_points(X, rvec, tvec, K, dist).points + rng.normal(0.0, sigma, (len(X), 2))
        obj.append(X.astype(np.float32).astype(np.float64))
        img.append(uv.astype(np.float32).astype(np.float64))
    return obj, img, (1280, 720)


def best_of(fn: Callable[[], object], n: int) -> float:
    """Return the best wall-clock time (s) of n calls."""
    best = np.inf
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def bench_speed(n: int = 30) -> None:
    obj, img, size = synthetic_views()
    obj32 = [o.astype(np.float32) for o in obj]
    img32 = [i.astype(np.float32) for i in img]
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 30, np.finfo(float).eps)

    def ours() -> object:
        return calibrate_camera(obj, img, size, distortion="k1k2p1p2k3")

    def opencv() -> object:
        return cv2.calibrateCamera(obj32, img32, size, None, None, criteria=crit)

    c = ours()
    rms_cv, K_cv, d_cv, _, _ = opencv()  # type: ignore[misc]
    # Interleaved rounds, best of each: a busy machine slows both alike.
    t_ours, t_cv = np.inf, np.inf
    for _ in range(n):
        t_ours = min(t_ours, best_of(ours, 1))
        t_cv = min(t_cv, best_of(opencv, 1))
    print("Zhang calibration, 20 views x 100 points, distortion k1 k2 p1 p2 k3")
    print(f"  ours   : {t_ours * 1e3:8.2f} ms  rms {c.rms:.9f} px  ({c.iterations} LM iterations)")
    print(f"  OpenCV : {t_cv * 1e3:8.2f} ms  rms {rms_cv:.9f} px")
    print(
        f"  |rms difference| {abs(c.rms - rms_cv):.2e} px;  max |K difference| "
        f"{np.abs(c.K - K_cv).max():.2e} px;  max |dist difference| "
        f"{np.abs(c.dist - d_cv.ravel()).max():.2e}"
    )
    print(f"  time ratio ours / OpenCV = {t_ours / t_cv:.2f} (target <= 1.5)")
    profile_split(obj, img, size, c.iterations, t_ours)


def profile_split(
    obj: list, img: list, size: tuple[int, int], iterations: int, total: float
) -> None:
    """Print where our time goes: closed form, Jacobian and residual evaluations, the rest."""
    m = len(obj)
    X = np.stack(obj)
    uv = np.stack(img)
    c = calibrate_camera(obj, img, size, distortion="k1k2p1p2k3")
    sel = np.zeros((10, 9))
    free = [0, 1, 2, 3, 5, 6, 7, 8, 9]
    sel[free, np.arange(9)] = 1.0
    problem = ReprojectionProblem(X, uv, np.ones(X.shape[:2], bool), np.zeros(10), sel)
    g = np.array([c.K[0, 0], c.K[1, 1], c.K[0, 2], c.K[1, 2], *c.dist])
    loc = np.concatenate([c.rvecs, c.tvecs], 1)

    def closed_form() -> None:
        Hs = np.stack([dlt_homography(o[:, :2], i) for o, i in zip(obj, img, strict=True)])
        pose_from_homography(Hs, intrinsics_from_homographies(Hs, size, skew=False), X[..., :2])

    t_closed = best_of(closed_form, 20)
    t_jac = best_of(lambda: problem.jacobians(g, loc), 50)
    t_res = best_of(lambda: problem.residuals(g, loc), 50)
    # The LM evaluates one Jacobian and one trial residual per iteration (plus the start).
    t_eval = (iterations + 1) * t_jac + iterations * t_res
    print(
        f"  profile ({m * len(obj[0])} points, {iterations} iterations): closed form "
        f"{t_closed * 1e3:.2f} ms; Jacobian {t_jac * 1e3:.3f} ms and residuals "
        f"{t_res * 1e3:.3f} ms per evaluation ({t_eval * 1e3:.2f} ms in all); "
        f"LM linear algebra and the rest {(total - t_closed - t_eval) * 1e3:.2f} ms"
    )


def zhang_real_data() -> None:
    if not DATA.is_dir():
        print(f"Zhang's data not found at {DATA}; skipped")
        return
    model, img = read_zhang()
    c = calibrate_camera([model] * 5, img, (640, 480), skew=True, distortion="k1k2")
    ours = zhang_values(c)
    print("Zhang's real data (5 views x 256 points), skew and k1 k2, vs published")
    for name, text in PUBLISHED.items():
        pub, digits = float(text), decimals(text)
        mark = "ok" if round(ours[name], digits) == pub else "differs in the last digit"
        print(f"  {name:6s} ours {ours[name]:14.8f}  published {pub:<10}  {mark}")
    print(f"  rms {c.rms:.6f} px per point;  LM iterations {c.iterations}")
    print(f"  view 1: R = {np.array2string(c.poses[0].R, precision=6)}")
    print(f"          t = {np.array2string(c.poses[0].t, precision=5)}")
    # Without skew, against OpenCV on the same (float32) points.
    model32 = model.astype(np.float32)
    img32 = [i.astype(np.float32) for i in img]
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, np.finfo(float).eps)
    flags = cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
    obj32 = [np.c_[model32, np.zeros(len(model32), np.float32)]] * 5
    rms, K, d, _, _ = cv2.calibrateCamera(
        obj32, img32, (640, 480), None, None, flags=flags, criteria=crit
    )
    c0 = calibrate_camera(
        [model32.astype(float)] * 5, [i.astype(float) for i in img32], (640, 480), distortion="k1k2"
    )
    print(
        "  without skew: ours fx, fy, cx, cy, k1, k2 = "
        f"{c0.K[0, 0]:.6f} {c0.K[1, 1]:.6f} {c0.K[0, 2]:.6f} {c0.K[1, 2]:.6f} "
        f"{c0.dist[0]:.8f} {c0.dist[1]:.8f}, rms {c0.rms:.10f}"
    )
    print(
        "              OpenCV fx, fy, cx, cy, k1, k2 = "
        f"{K[0, 0]:.6f} {K[1, 1]:.6f} {K[0, 2]:.6f} {K[1, 2]:.6f} "
        f"{d.ravel()[0]:.8f} {d.ravel()[1]:.8f}, rms {rms:.10f}"
    )


if __name__ == "__main__":
    bench_speed()
    zhang_real_data()
