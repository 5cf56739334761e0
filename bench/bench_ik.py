"""Benchmark: numerical inverse kinematics of the twin's arm against roboticstoolbox-python.

Run from the repository root: `python -m bench.bench_ik [--poses 1000] [--seed 0]`
(roboticstoolbox is in the `bench` extra only).

The same arm (core.manipulation.default_arm(): the Puma 560's standard DH geometry, its joint
limits, a 0.12 m tool) is built as an rtb DHRobot; its forward kinematics is checked against
ours first. Targets: fk of `poses` joint vectors drawn uniformly within the limits (every target
reachable). Each solver's success is judged by the TRUE error of its answer, recomputed with
our fk: position <= 1e-9 m and rotation <= 1e-9 rad, joints within limits (its own success flag
accepts residuals near 1e-6, about a millimetre). rtb runs with its defaults and again with
tol = 1e-20 (its residual E = 0.5 e^T e, so errors near 1e-10). Prints success rate, median and
max true errors, mean time per solve (wall and CPU), and the closed-form IK's branch count and
round trip; then the closed form's solution sets against EAIK's (`eaik`, bench-only, run in its
own venv, default /tmp/intspace-eaik-venv or $INTSPACE_EAIK_VENV, made on first use).
`--skip-rtb`, `--skip-eaik` leave an anchor out.
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

from core.manipulation import default_arm, pose_error

EAIK_VENV = Path(os.environ.get("INTSPACE_EAIK_VENV", "/tmp/intspace-eaik-venv"))

# Runs in the eaik venv: every closed-form solution of each flange pose (EAIK, Ostermeier et
# al., "Automatic geometric decomposition for analytical inverse kinematics", 2025).
EAIK_CHILD = r"""
import sys
import numpy as np
from eaik.IK_DH import DhRobot

d = np.load(sys.argv[1])
bot = DhRobot(d["alpha"], d["a"], d["d"])
T = d["T"]
Q = np.full((len(T), 16, 6), np.nan)
LS = np.ones((len(T), 16), dtype=bool)
for k, t in enumerate(T):
    s = bot.IK(t)
    n = min(len(s.Q), 16)
    Q[k, :n], LS[k, :n] = s.Q[:n], s.is_LS[:n]
np.savez(sys.argv[2], Q=Q, LS=LS)
"""


def ensure_eaik() -> Path:
    """Return the python of a venv with eaik (created on first use; bench-only)."""
    py = EAIK_VENV / "bin" / "python"
    if (
        py.exists()
        and subprocess.run([str(py), "-c", "import eaik"], capture_output=True).returncode == 0
    ):
        return py
    print(f"creating {EAIK_VENV} with eaik ...", flush=True)
    subprocess.run([sys.executable, "-m", "venv", str(EAIK_VENV)], check=True)
    subprocess.run([str(py), "-m", "pip", "install", "-q", "eaik", "numpy"], check=True)
    return py


def compare_with_eaik(targets: np.ndarray, ours: list[list[np.ndarray]]) -> None:
    """Print whether our closed-form branch sets equal EAIK's (its exact solutions wrapped to
    (-pi, pi], kept within the limits with every 2 pi shift there, as ik_analytic returns)."""
    arm = default_arm()
    py = ensure_eaik()
    flange = targets @ np.linalg.inv(arm.tool)
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "in.npz", Path(tmp) / "out.npz"
        np.savez(src, alpha=arm.alpha, a=arm.a, d=arm.d, T=flange)
        subprocess.run([str(py), "-c", EAIK_CHILD, str(src), str(dst)], check=True)
        out = np.load(dst)
        Q, LS = out["Q"], out["LS"]
    same = 0
    worst = 0.0
    for k, mine in enumerate(ours):
        ref = []
        for q, ls in zip(Q[k], LS[k], strict=True):
            if ls or not np.all(np.isfinite(q)):
                continue
            w = -((-q + np.pi) % (2 * np.pi) - np.pi)
            ref.extend(arm._shifted(w))
        if len(ref) != len(mine):
            continue
        # Match every branch one to one (greedy on the max-norm distance).
        left = list(mine)
        ok = True
        for r in ref:
            dists = [float(np.max(np.abs(r - m))) for m in left]
            j = int(np.argmin(dists))
            worst = max(worst, dists[j])
            if dists[j] > 1e-9:
                ok = False
                break
            left.pop(j)
        same += ok
    print(
        f"closed form vs EAIK: identical solution sets (within limits, 2 pi shifts) for "
        f"{same} of {len(ours)} poses; largest joint difference {worst:.1e} rad"
    )


def rtb_arm():  # type: ignore[no-untyped-def]
    import roboticstoolbox as rtb
    from spatialmath import SE3

    arm = default_arm()
    links = [
        rtb.RevoluteDH(d=arm.d[i], a=arm.a[i], alpha=arm.alpha[i], qlim=arm.limits[i])
        for i in range(6)
    ]
    return rtb.DHRobot(links, name="puma-like", tool=SE3(arm.tool)), rtb.DHRobot(
        links, name="puma-like-flange"
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--poses", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--skip-rtb", action="store_true")
    ap.add_argument("--skip-eaik", action="store_true")
    args = ap.parse_args()
    arm = default_arm()
    robot, flange_robot = rtb_arm()
    rng = np.random.default_rng(args.seed)
    qs = rng.uniform(arm.limits[:, 0], arm.limits[:, 1], (args.poses, 6))
    targets = arm.fk(qs)
    # rtb's C++ ik_LM ignores a DHRobot's tool (its answers land 0.12 m off), so both rtb
    # solvers get the flange's pose T tool^-1 on the tool-less robot; the tool is rigid, so the
    # end effector's true error is judged the same way (our fk, with the tool).
    flange_targets = targets @ np.linalg.inv(arm.tool)
    fk_rtb = np.array([robot.fkine(q).A for q in qs[:50]])
    print(f"fk agreement with rtb (50 poses): max |dT| = {np.abs(fk_rtb - targets[:50]).max():.2e}")

    def judge(name: str, sols: list[np.ndarray], seconds: float) -> None:
        Q = np.array(sols)
        dp, dr = pose_error(arm.fk(Q), targets)
        ok = (dp <= 1e-9) & (dr <= 1e-9) & arm.within_limits(Q, tol=1e-12)
        print(
            f"{name:<26} {100 * ok.mean():>8.2f} % {np.median(dp):>10.1e} {dp.max():>9.1e} "
            f"{np.median(dr):>10.1e} {dr.max():>9.1e} {1e3 * seconds / len(sols):>9.3f}"
        )

    print(
        f"{'solver':<26} {'success':>10} {'pos med m':>10} {'pos max':>9} {'rot med':>10} "
        f"{'rot max':>9} {'ms/solve':>9}"
    )
    t0 = time.perf_counter()
    c0 = time.process_time()
    ours = [arm.ik(T) for T in targets]
    t_ours = time.perf_counter() - t0
    c_ours = time.process_time() - c0
    judge("intspace ik (LM)", [r.q for r in ours], t_ours)
    print(f"{'':<26} CPU time {1e3 * c_ours / len(targets):.3f} ms/solve (wall time above)")
    print(
        f"{'':<26} mean iterations {np.mean([r.iterations for r in ours]):.1f}, "
        f"random restarts {np.mean([r.restarts for r in ours]):.3f} per solve"
    )
    anchor = {}
    for label, kw in () if args.skip_rtb else (("", {}), (" tol 1e-20", {"tol": 1e-20})):
        seed_rng = np.random.default_rng(args.seed)
        t0 = time.perf_counter()
        sols = [flange_robot.ik_LM(T, **kw).q for T in flange_targets]
        anchor[label] = time.perf_counter() - t0
        judge("rtb ik_LM (C++)" + label, sols, anchor[label])
        t0 = time.perf_counter()
        sols = [
            flange_robot.ikine_LM(T, seed=int(seed_rng.integers(1 << 31)), **kw).q
            for T in flange_targets
        ]
        judge("rtb ikine_LM (Python)" + label, sols, time.perf_counter() - t0)

    if anchor:
        print(
            f"time per solve, intspace ik / rtb ik_LM (C++, tol 1e-20, the one at 1e-9): "
            f"{t_ours / anchor[' tol 1e-20']:.2f}x"
        )
    t0 = time.perf_counter()
    branches = [arm.ik_analytic(T) for T in targets]
    t_an = time.perf_counter() - t0
    worst = max(
        max(pose_error(arm.fk(np.array(b)), T)[0].max(), 0.0)
        for b, T in zip(branches, targets, strict=True)
        if b
    )
    found = np.mean(
        [
            min(np.abs(np.array(b) - q).max() for b in bs) < 1e-9
            for bs, q in zip(branches, qs, strict=True)
            for b in [bs]
            if bs
        ]
    )
    counts = np.bincount([len(b) for b in branches])
    if not args.skip_eaik:
        compare_with_eaik(targets, branches)
    print(
        f"closed form: {1e3 * t_an / len(targets):.3f} ms/solve, branches per pose "
        f"{dict(enumerate(counts.tolist()))}, worst position error {worst:.1e} m, "
        f"source configuration among the branches {100 * found:.1f} %"
    )


if __name__ == "__main__":
    main()
