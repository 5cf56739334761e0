"""The one tracker's throughput: ten unsynchronised cameras at 10 Hz, twenty people, one core.

Run from the repository root: python -m bench.bench_tracking
Scene: a 16 m x 12 m floor (four rooms of the bench_localization room side by side), ten
ceiling cameras at 2.8 m (1280 x 800, barrel distortion) each at 10 Hz with its own phase,
twenty people walking smooth closed paths at up to ~0.8 m/s, detections of a point at 1.0 m
with 0.7 px noise, 5 % missed and Poisson(0.3) clutter per frame: 60 s of frames. The frames
are simulated first; only the tracker's calls are timed (time.perf_counter, whole run, one
core). The anchor is real time: the cameras produce 100 frames/s, so the ratio says how many
times faster than the cameras the tracker runs (spec 08: >= 1). Also prints the
position RMSE of the confirmed tracks and the most live tracks at once.
"""

from __future__ import annotations

import os

# One core: pin the BLAS and OpenMP pools before numpy loads them.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import time  # noqa: E402

import numpy as np  # noqa: E402

from core.localization import NetworkCamera  # noqa: E402
from core.localization.tracking import Tracker, TrackState  # noqa: E402

N_TARGETS = 20
N_CAMERAS = 10
RATE = 10.0
DURATION = 60.0
SIGMA = 0.7
HEIGHT = 1.0
FLOOR = (16.0, 12.0)


def make_cameras() -> list[NetworkCamera]:
    """Return ten ceiling cameras along the walls of the floor, looking inwards and down."""
    w, d = FLOOR
    dist = np.array([-0.12, 0.03, 5e-4, -3e-4, -2e-3])
    spots = [(x, 0.2) for x in (2.0, 6.0, 10.0, 14.0)] + [
        (x, d - 0.2) for x in (2.0, 6.0, 10.0, 14.0)
    ]
    spots += [(0.2, d / 2), (w - 0.2, d / 2)]
    cams = []
    for i, (x, y) in enumerate(spots):
        f = 700.0 + 10.0 * i
        K = np.array([[f, 0.0, 640.0 + i], [0.0, f, 400.0 - i], [0.0, 0.0, 1.0]])
        target = (x + 0.45 * (w / 2 - x), y + 0.45 * (d / 2 - y), 0.0)
        cams.append(NetworkCamera.looking_at(K, dist, (x, y, 2.8), target, (1280, 800), f"cam{i}"))
    return cams


def trajectories(t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Return positions (T, N, 2) at times t (T,): Lissajous paths inside the floor."""
    centre = rng.uniform([3.0, 3.0], [13.0, 9.0], (N_TARGETS, 2))
    amp = rng.uniform(0.5, 2.0, (N_TARGETS, 2))
    omega = rng.uniform(0.1, 0.3, (N_TARGETS, 2))
    phase = rng.uniform(0, 2 * np.pi, (N_TARGETS, 2))
    return centre + amp * np.sin(omega * t[:, None, None] + phase)


def frames(cams: list[NetworkCamera], rng: np.random.Generator):
    """Return the camera frames in time order: (t, camera, pixels (D, 2)), and the truth."""
    out = []
    for k, cam in enumerate(cams):
        t = rng.uniform(0, 1 / RATE) + np.arange(0.0, DURATION, 1 / RATE)
        xy = trajectories(t, np.random.default_rng(7))
        for i in range(t.size):
            P = np.column_stack([xy[i], np.full(N_TARGETS, HEIGHT)])
            seen = cam.in_view(P) & (rng.random(N_TARGETS) >= 0.05)
            px = cam.project(P[seen]) + rng.normal(0.0, SIGMA, (int(seen.sum()), 2))
            n = rng.poisson(0.3)
            fake = np.column_stack([rng.uniform(0, 1280, n), rng.uniform(0, 800, n)])
            out.append((float(t[i]), k, np.vstack([px, fake])))
    out.sort(key=lambda f: (f[0], f[1]))
    return out


def main() -> None:
    rng = np.random.default_rng(0)
    cams = make_cameras()
    data = frames(cams, rng)
    tracker = Tracker(cams)
    cov = np.eye(2) * SIGMA**2
    most_live = 0
    wall = 0.0
    for t, k, px in data:
        start = time.perf_counter()
        tracker.update(k, t, px, cov, heights=HEIGHT, kinds="person")
        wall += time.perf_counter() - start
        live = sum(s.state is not TrackState.TENTATIVE for s in tracker.tracks())
        most_live = max(most_live, live)
    truth_final = trajectories(np.array([data[-1][0]]), np.random.default_rng(7))[0]
    final = [s.xy for s in tracker.tracks() if s.state is TrackState.CONFIRMED]
    d = np.linalg.norm(np.array(final)[:, None] - truth_final[None], axis=2).min(axis=1)
    n_det = sum(len(f[2]) for f in data)
    fps = len(data) / wall
    print(f"tracker: {N_CAMERAS} cameras x {RATE:g} Hz, {N_TARGETS} people, {DURATION:g} s")
    print(f"  frames/s     {fps:10.0f}   (cameras produce {N_CAMERAS * RATE:.0f}/s)")
    print(f"  detections/s {n_det / wall:10.0f}")
    print(f"  ratio to real time: {fps / (N_CAMERAS * RATE):.1f}x (target >= 1)")
    print(f"  confirmed at the end {len(final)} of {N_TARGETS}, most live at once {most_live}")
    print(f"  final position error: median {1000 * np.median(d):.1f} mm, max {1000 * d.max():.1f}")


if __name__ == "__main__":
    main()
