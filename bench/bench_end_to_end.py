"""The twin as cameras, end to end (spec 08): twin -> MJPEG -> `intspace node` -> REST ->
tracker -> WebSocket, against the in-process path (the twin detecting in its own frames).

Run from the repository root:
    python -m bench.bench_end_to_end [--seconds 60] [--seed 0] [--tracker-latency S] [--node-only]

Each path is `intspace serve` as a user starts it (a subprocess, SQLite under a fresh data
folder, the admin token from the environment, the default home at the default 5 frames per
second), once with INTSPACE_TWIN_DETECTION=external and one `intspace node` reading the MJPEG
streams of all the space's cameras (an ingest token bound to them, a YAML file naming the
space), once with INTSPACE_TWIN_DETECTION=internal. The two run side by side (the same load
on the machine) and are scored on the same window of simulated time: the robot drives the
same stretch of its patrol in front of the same people in both (from 3 s of simulated time
on). Their RMSEs are also compared over the steps both scored (paired).

Scoring, from outside the service, by its public API only:

* Truth: GET /twin returns the simulated time and the robot's true pose, read together under
  the twin's lock (the truth is for scoring; no estimator reads it). Polled at 25 Hz, each
  twin step (one frame of every camera, 0.2 s apart) is seen with the interval its capture
  time lies in: after the last answer that showed the previous step was sent, before the
  first answer that shows it came back (a few tens of milliseconds).
* Estimate: the robot target's stored track points (GET /targets/{id}/track), each at its
  observation's own capture time, which is exactly one step's capture time. A point is scored
  against the pose of that step; points of steps the polling missed are not scored (counted).
* Latency: a WebSocket client on /ws/targets notes when each positions message arrives; the
  capture-to-WebSocket latency of a frame stamped T (X-Timestamp, Unix seconds on the
  service's clock, which is this machine's) is the arrival of the first message whose robot
  target's own time (`t`, its last update's observation time) is >= T, minus T, for every
  robot track point's T. The twin stamps an instant when all its cameras' frames exist (so
  its rendering is not counted); the latency holds the node's reading, decoding, detecting
  and posting (or the twin's detecting, in process), the wait in the tracker's reorder buffer
  for the instant's last camera frame (each camera posts every frame, empty ones too; the
  window INTSPACE_TRACKER_LATENCY_S is the longest wait), the tracker's update and the
  stream's slot (at most 30 messages a second).
* Where it goes: the tracker and the node report the delays of their stages when they stop
  (capture to arrival at the service, reorder wait, tracker update; for the node, capture to
  its reception of the frame, waiting for the detector, decoding and detecting, capture to
  the service's answer); they are printed per path. The service prints them only when its
  log shows INFO messages.

Prints per path the robot's RMSE, the twin's own in-service figure where it has one (its
labelled robot, the in-process path only), the points scored and the share of the window's
steps they cover, the latency p50/p95; for the node, the detections it posted and the camera
frames the tracker refused as later than its reorder window, and per camera the frames per
second it was read at and the frames replaced before detection (none when the node keeps up).
The node's decode-and-detect throughput per camera on one core is bench/bench_node.py's.
"""

from __future__ import annotations

import argparse
import tempfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.end_to_end_paths import WINDOW_START_S, PathRun, Window, run_path


@dataclass(frozen=True)
class Paired:
    """Both paths' robot RMSE over the steps both have a track point at."""

    steps: int
    external_rmse_m: float
    internal_rmse_m: float

    @property
    def ratio(self) -> float:
        """Return the node path's RMSE over the in-process path's."""
        return self.external_rmse_m / self.internal_rmse_m


def paired(external: PathRun, internal: PathRun) -> Paired:
    """Return the RMSE of both paths over the steps both scored (one point per step each: a
    step's first, should a broken track give it two)."""

    def per_step(run: PathRun) -> dict[float, float]:
        out: dict[float, float] = {}
        for sim, error in zip(run.sim.tolist(), run.errors.tolist(), strict=True):
            out.setdefault(round(sim, 6), error)
        return out

    a, b = per_step(external), per_step(internal)
    common = sorted(set(a) & set(b))
    ea = np.array([a[k] for k in common])
    eb = np.array([b[k] for k in common])
    nan = float("nan")
    return Paired(
        steps=len(common),
        external_rmse_m=float(np.sqrt(np.mean(ea**2))) if common else nan,
        internal_rmse_m=float(np.sqrt(np.mean(eb**2))) if common else nan,
    )


def compare(
    folder: Path,
    *,
    seconds: float,
    start: float = WINDOW_START_S,
    seed: int = 0,
    tracker_latency_s: float | None = None,
    timeout_s: float | None = None,
) -> tuple[PathRun, PathRun]:
    """Return the node's path and the in-process path, run side by side (the same machine
    load) and scored over the same window of simulated time, [start, start + seconds];
    `tracker_latency_s` sets both services' INTSPACE_TRACKER_LATENCY_S (None: the default),
    `timeout_s` the wall time a path may take to reach the window's end (None: run_path's)."""
    window = Window(start, seconds)
    with ThreadPoolExecutor(max_workers=2) as pool:
        runs = [
            pool.submit(
                run_path,
                detection,
                folder / detection,
                window,
                seed=seed,
                tracker_latency_s=tracker_latency_s,
                timeout_s=timeout_s,
            )
            for detection in ("external", "internal")
        ]
        return runs[0].result(), runs[1].result()


def describe(run: PathRun) -> str:
    """Return one path's figures as lines of text."""
    lines = [
        f"{run.detection} detection: simulated time {run.window[0]:.1f}..{run.window[1]:.1f} s, "
        f"{run.errors.size} robot track points scored, {100 * run.coverage:.0f} % of its "
        f"{run.steps} steps ({run.unmatched} points of the run unmatched), "
        f"{run.seconds:.0f} s wall time (healthy after {run.healthy_s:.1f} s, robot on the "
        f"WebSocket after {run.first_robot_s:.1f} s)",
        f"  robot RMSE {100 * run.rmse_m:.2f} cm, max {100 * float(np.max(run.errors)):.2f} cm"
        if run.errors.size
        else "  no robot track point in the window",
        f"  capture-to-WebSocket latency p50 {1000 * run.latency_percentile(50):.0f} ms, "
        f"p95 {1000 * run.latency_percentile(95):.0f} ms",
    ]
    if run.twin_rmse_m is not None:
        lines.append(f"  the twin's own robot RMSE (its last 200 updates): {run.twin_rmse_m:.4f} m")
    if run.posted is not None:
        lines.append(
            f"  node: {run.posted} detections posted, {run.late_frames} camera frames refused by "
            "the tracker as later than its reorder window"
        )
    lines += [f"  {line}" for line in run.stages]
    for name, health in run.cameras.items():
        lines.append(
            f"  node camera {name}: {health['status']}, {health['fps']:.1f} frames/s read, "
            f"{health['dropped']} replaced before detection, {health['stalls']} stalls, "
            f"{health['reconnects']} reconnects"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="simulated seconds scored")
    parser.add_argument("--seed", type=int, default=0, help="the twin's seed")
    parser.add_argument(
        "--tracker-latency",
        type=float,
        metavar="S",
        help="INTSPACE_TRACKER_LATENCY_S of both services (default: the service's default)",
    )
    parser.add_argument(
        "--timeout",
        type=float,
        metavar="S",
        help="wall seconds a path may take to reach the window's end (default: 120 + 5 x its "
        "end; a loaded machine runs the twin slower than real time)",
    )
    parser.add_argument(
        "--node-only",
        action="store_true",
        help="run the node's path alone (its latency without a second service and twin "
        "sharing the machine); no ratio",
    )
    args = parser.parse_args(argv)
    if args.node_only:
        with tempfile.TemporaryDirectory(prefix="intspace-e2e-") as tmp:
            run = run_path(
                "external",
                Path(tmp) / "external",
                Window(WINDOW_START_S, args.seconds),
                seed=args.seed,
                tracker_latency_s=args.tracker_latency,
                timeout_s=args.timeout,
            )
        print(describe(run))
        p95 = run.latency_percentile(95)
        print(
            f"node path alone, capture-to-WebSocket p95: {1000 * p95:.0f} ms (spec 08: <= 200 ms)"
        )
        return 0
    with tempfile.TemporaryDirectory(prefix="intspace-e2e-") as tmp:
        external, internal = compare(
            Path(tmp),
            seconds=args.seconds,
            seed=args.seed,
            tracker_latency_s=args.tracker_latency,
            timeout_s=args.timeout,
        )
    window = "default" if args.tracker_latency is None else f"{args.tracker_latency:g} s"
    print(f"tracker reorder window (INTSPACE_TRACKER_LATENCY_S): {window}, seed {args.seed}")
    print(describe(external))
    print(describe(internal))
    both = paired(external, internal)
    print(
        f"over the {both.steps} steps both paths scored: robot RMSE node path "
        f"{100 * both.external_rmse_m:.2f} cm, in-process {100 * both.internal_rmse_m:.2f} cm, "
        f"ratio {both.ratio:.2f} (spec 08: <= 1.2)"
    )
    p95 = external.latency_percentile(95)
    print(f"node path capture-to-WebSocket p95: {1000 * p95:.0f} ms (spec 08: <= 200 ms)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
