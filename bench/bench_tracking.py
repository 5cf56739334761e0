"""Floor tracker: update rate with four cameras and ten targets, from pixels and from floor points.

Run from the repository root: python -m bench.bench_tracking
Scene: the 8 m x 6 m room of bench_localization (four corner cameras at 2.8 m, 1280 x 800,
barrel distortion), ten people walking smooth closed paths at up to ~0.8 m/s, detections at
Z = 0 with pixel noise sigma = 0.5 px, 2000 frames at 30 Hz. The detections are simulated
first; only the tracker's calls are timed (time.perf_counter, whole run, one core). Prints
frames/s and inputs/s for `update_detections` (per-camera association + ML fusion) and
for `update` (floor positions), and the position RMSE of the confirmed tracks.
"""

from __future__ import annotations

import os

# One core: pin the BLAS and OpenMP pools before numpy loads them.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import time  # noqa: E402

import numpy as np  # noqa: E402

from bench.bench_localization import make_cameras  # noqa: E402
from core.localization import NetworkCamera, locate_ml  # noqa: E402
from core.localization.tracking import FloorTracker, TrackerConfig  # noqa: E402

N_TARGETS = 10
N_FRAMES = 2000
RATE = 30.0
SIGMA = 0.5
HEIGHT = 0.0


def trajectories(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Return times (F,) and positions (F, N, 2): Lissajous paths inside the room."""
    t = np.arange(N_FRAMES) / RATE
    centre = rng.uniform([2.5, 2.0], [5.5, 4.0], (N_TARGETS, 2))
    amp = rng.uniform(0.5, 1.5, (N_TARGETS, 2))
    omega = rng.uniform(0.15, 0.35, (N_TARGETS, 2))
    phase = rng.uniform(0, 2 * np.pi, (N_TARGETS, 2))
    xy = centre + amp * np.sin(omega * t[:, None, None] + phase)
    return t, xy


def detections(
    cams: list[NetworkCamera], xy: np.ndarray, rng: np.random.Generator
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Return per frame (camera index (D,), pixels (D, 2)) of the visible targets, shuffled."""
    frames = []
    for f in range(xy.shape[0]):
        P = np.column_stack([xy[f], np.full(N_TARGETS, HEIGHT)])
        idx, px = [], []
        for k, cam in enumerate(cams):
            seen = cam.in_view(P)
            idx.append(np.full(int(seen.sum()), k))
            px.append(cam.project(P[seen]) + rng.normal(0.0, SIGMA, (int(seen.sum()), 2)))
        order = rng.permutation(sum(i.size for i in idx))
        frames.append((np.concatenate(idx)[order], np.vstack(px)[order]))
    return frames


def rmse(tracker: FloorTracker, truth: np.ndarray) -> float:
    """Return the RMS distance from each truth to its nearest confirmed track, metres."""
    xy = np.array([tr.xy for tr in tracker.tracks(confirmed_only=True)])
    d = np.linalg.norm(truth[:, None] - xy[None], axis=2).min(axis=1)
    return float(np.sqrt(np.mean(d**2)))


def main() -> None:
    rng = np.random.default_rng(0)
    cams = make_cameras()
    t, xy = trajectories(rng)
    frames = detections(cams, xy, rng)
    n_det = sum(c.size for c, _ in frames)
    cfg = TrackerConfig(q=0.5, height=HEIGHT)

    tracker = FloorTracker(cfg, cameras=cams)
    errors = []
    wall_px = 0.0
    for f, (cam, px) in enumerate(frames):
        t0 = time.perf_counter()
        tracker.update_detections(t[f], cam, px, pixel_sigma=SIGMA)
        wall_px += time.perf_counter() - t0
        if f % 100 == 99:
            errors.append(rmse(tracker, xy[f]))
    n_tracks = len(tracker.tracks(confirmed_only=True))

    # The floor entry point, fed with the same scene located by ML beforehand (grouped by the
    # simulator's truth), so that only the tracker is timed.
    floor = []
    for f in range(N_FRAMES):
        pixels = np.zeros((len(cams), N_TARGETS, 2))
        vis = np.zeros((len(cams), N_TARGETS), dtype=bool)
        P = np.column_stack([xy[f], np.full(N_TARGETS, HEIGHT)])
        for k, c in enumerate(cams):
            vis[k] = c.in_view(P)
            pixels[k] = c.project(P) + rng.normal(0.0, SIGMA, (N_TARGETS, 2))
        est = locate_ml(cams, pixels, HEIGHT, visible=vis, pixel_sigma=SIGMA)
        floor.append((est.xy[est.valid], est.cov[est.valid]))
    tracker_xy = FloorTracker(cfg)
    t0 = time.perf_counter()
    for f, (z, R) in enumerate(floor):
        tracker_xy.update(t[f], z, R)
    wall_xy = time.perf_counter() - t0
    n_meas = sum(z.shape[0] for z, _ in floor)

    print(
        f"Floor tracker: {len(cams)} cameras, {N_TARGETS} targets, {N_FRAMES} frames at "
        f"{RATE:.0f} Hz, sigma = {SIGMA} px"
    )
    print(f"{'entry point':<20}  {'frames/s':>10}  {'inputs/s':>10}  {'ms/frame':>9}")
    print("-" * 56)
    print(
        f"{'update_detections':<20}  {N_FRAMES / wall_px:>10.0f}  {n_det / wall_px:>10.0f}  "
        f"{1e3 * wall_px / N_FRAMES:>9.3f}"
    )
    print(
        f"{'update (floor xy)':<20}  {N_FRAMES / wall_xy:>10.0f}  {n_meas / wall_xy:>10.0f}  "
        f"{1e3 * wall_xy / N_FRAMES:>9.3f}"
    )
    print(
        f"(inputs: {n_det / N_FRAMES:.1f} pixel detections or {n_meas / N_FRAMES:.1f} floor "
        "points per frame; spec 02 asks >= 30 frames/s)"
    )
    print(
        f"confirmed tracks at the end: {n_tracks} of {N_TARGETS} targets; position RMSE "
        f"(every 100th frame): {1e3 * float(np.sqrt(np.mean(np.square(errors)))):.1f} mm"
    )


if __name__ == "__main__":
    main()
