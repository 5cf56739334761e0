"""Benchmark: hand-eye calibration against OpenCV 4's cv2.calibrateHandEye (five methods).

Run from the repository root: `python -m bench.bench_hand_eye [--trials 100] [--views 15]`.

The project's OpenCV 5 wheel has no calibrateHandEye, so this script makes a small virtual
environment with `opencv-python-headless<5` (default /tmp/intspace-opencv4-venv, or
$INTSPACE_OPENCV4_VENV) and runs the anchor there in a subprocess; the two sides exchange the
same data through .npz files.

Data: the twin's arm shows its eye-in-hand camera the table's chessboard (8 x 5 corners, 25 mm)
from `views` reachable poses (core.sim.eye_in_hand.hand_eye_views: the last 3 are
pure translations of the first, the two-group method's first group), true projections plus
0.5 px Gaussian noise per axis; each view's board pose from its pixels
(core.calibration.estimate_plane_pose) on the camera's own calibration (Zhang on rendered
chessboard views, made once). Every method gets the same poses. Prints the median (and 90th
percentile) rotation error (deg) and translation error (mm) over `trials` trials of our five
linear methods (Tsai, Park, Daniilidis, Andreff, the thesis's two-group), our reprojection
refinement, and OpenCV's TSAI, PARK, HORAUD, ANDREFF
and DANIILIDIS. Spec 05's goal: refinement <= 0.1 deg and <= 1 mm, better than OpenCV's best.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from core.manipulation import METHODS, pose_error
from core.sim.eye_in_hand import eye_camera_intrinsics, hand_eye_views

VENV = Path(os.environ.get("INTSPACE_OPENCV4_VENV", "/tmp/intspace-opencv4-venv"))

CHILD = r"""
import sys
import cv2
import numpy as np

d = np.load(sys.argv[1])
names = ["TSAI", "PARK", "HORAUD", "ANDREFF", "DANIILIDIS"]
T = d["R_g2b"].shape[0]
R = np.zeros((T, len(names), 3, 3))
t = np.zeros((T, len(names), 3))
for k in range(T):
    for j, name in enumerate(names):
        r, tt = cv2.calibrateHandEye(
            list(d["R_g2b"][k]), list(d["t_g2b"][k]), list(d["R_t2c"][k]), list(d["t_t2c"][k]),
            method=getattr(cv2, "CALIB_HAND_EYE_" + name),
        )
        R[k, j], t[k, j] = r, tt.ravel()
np.savez(sys.argv[2], R=R, t=t, names=np.array(names), version=np.array(cv2.__version__))
"""


def ensure_opencv4() -> Path:
    """Return the python of a venv with OpenCV 4 (created on first use)."""
    py = VENV / "bin" / "python"
    probe = [str(py), "-c", "import cv2, sys; sys.exit(0 if cv2.__version__[0] == '4' else 1)"]
    if py.exists() and subprocess.run(probe, capture_output=True).returncode == 0:
        return py
    print(f"creating {VENV} with opencv-python-headless<5 ...", flush=True)
    subprocess.run([sys.executable, "-m", "venv", str(VENV)], check=True)
    subprocess.run(
        [str(py), "-m", "pip", "install", "-q", "opencv-python-headless<5", "numpy"], check=True
    )
    return py


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=100)
    ap.add_argument("--views", type=int, default=15)
    ap.add_argument("--sigma", type=float, default=0.5)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    intrinsics = eye_camera_intrinsics(rng)

    ours: dict[str, list[tuple[float, float]]] = {m: [] for m in [*METHODS, "park+refine"]}
    E_all, C_all, X_true = [], [], []
    t_lin = t_ref = 0.0
    for _ in range(args.trials):
        v = hand_eye_views(rng, views=args.views, sigma_px=args.sigma, intrinsics=intrinsics)
        E_all.append(v.T_base_ee)
        C_all.append(v.T_cam_target)
        X_true.append(v.true_X)
        for m in METHODS:
            t0 = time.perf_counter()
            r = v.calibrate(m)
            t_lin += time.perf_counter() - t0
            ours[m].append(pose_error(r.X, v.true_X))
        t0 = time.perf_counter()
        r = v.calibrate("park", refine=True)
        t_ref += time.perf_counter() - t0
        ours["park+refine"].append(pose_error(r.X, v.true_X))

    E = np.array(E_all)
    C = np.array(C_all)
    py = ensure_opencv4()
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "in.npz", Path(tmp) / "out.npz"
        np.savez(
            src,
            R_g2b=E[:, :, :3, :3],
            t_g2b=E[:, :, :3, 3:4],
            R_t2c=C[:, :, :3, :3],
            t_t2c=C[:, :, :3, 3:4],
        )
        subprocess.run([str(py), "-c", CHILD, str(src), str(dst)], check=True)
        out = np.load(dst)
        R_cv, t_cv = out["R"], out["t"]
        names = [str(n) for n in out["names"]]
        version = str(out["version"])
    cv: dict[str, list[tuple[float, float]]] = {}
    for j, name in enumerate(names):
        Xs = np.tile(np.eye(4), (args.trials, 1, 1))
        Xs[:, :3, :3], Xs[:, :3, 3] = R_cv[:, j], t_cv[:, j]
        dp, dr = pose_error(Xs, np.array(X_true))
        cv[f"opencv {name}"] = list(zip(dp, dr, strict=True))

    print(
        f"hand-eye, {args.trials} trials x {args.views} views, {args.sigma} px noise, seed "
        f"{args.seed}; OpenCV {version}"
    )
    print(
        f"{'method':<20} {'rot med deg':>12} {'rot p90':>9} {'trans med mm':>13} {'trans p90':>10}"
    )
    for name, errs in [*ours.items(), *cv.items()]:
        e = np.array(errs)
        rot, tr = np.degrees(e[:, 1]), 1e3 * e[:, 0]
        print(
            f"{name:<20} {np.median(rot):>12.4f} {np.percentile(rot, 90):>9.4f} "
            f"{np.median(tr):>13.3f} {np.percentile(tr, 90):>10.3f}"
        )
    n = args.trials
    print(
        f"time per calibration: linear {1e3 * t_lin / (len(METHODS) * n):.2f} ms, "
        f"refinement {1e3 * t_ref / n:.1f} ms"
    )


if __name__ == "__main__":
    main()
