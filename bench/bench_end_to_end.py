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
import json
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from numpy.typing import NDArray
from websockets.sync.client import connect

from tests.support.service import clean_env, start_service

REPO_ROOT = Path(__file__).resolve().parents[1]
TOKEN = "end-to-end-admin-token"
HEADERS = {"Authorization": f"Bearer {TOKEN}"}
# GET /twin every 40 ms: the twin's steps are 200 ms apart at its default 5 Hz, so each step's
# capture time is bracketed to a fraction of a step, and the service is barely loaded.
_POLL_S = 0.04
# A track point belongs to the step whose capture interval it lies in, give or take this much
# (s): the stamp is taken in the same locked block as the pose, so only the two processes'
# scheduling separates them; steps are 200 ms apart, so the match is never ambiguous.
_MATCH_SLACK_S = 0.03
# The scored window starts this far into the simulation (s): the node connects to the streams
# while the twin learns its cameras' backgrounds, before its first step, so by then it is
# reading them.
WINDOW_START_S = 3.0


class Service:
    """`intspace serve` with the twin (tests/support/service.py), detection `internal` or
    `external`, and a client of its API."""

    def __init__(
        self, data_dir: Path, detection: str, seed: int, tracker_latency_s: float | None = None
    ) -> None:
        env = {
            "INTSPACE_SIMULATION": "true",
            "INTSPACE_TWIN_DETECTION": detection,
            "INTSPACE_TWIN_SEED": str(seed),
            "INTSPACE_VISER_ENABLED": "false",
        }
        if tracker_latency_s is not None:
            env["INTSPACE_TRACKER_LATENCY_S"] = str(tracker_latency_s)
        self.served = start_service(data_dir, token=TOKEN, env=env, wait=False)
        self.api = self.served.api
        self.http = httpx.Client(base_url=self.api, headers=HEADERS, timeout=10)

    def wait_healthy(self) -> None:
        self.served.wait_healthy()

    def get(self, path: str, **params: Any) -> Any:
        response = self.http.get(path, params=params)
        if response.status_code != 200:
            raise RuntimeError(f"GET {path} answered {response.status_code}: {response.text}")
        return response.json()

    def stop(self) -> None:
        self.http.close()
        self.served.stop()


def start_node(service: Service, folder: Path) -> subprocess.Popen:
    """Start one `intspace node` reading every twin camera's MJPEG stream, with an ingest token
    bound to those cameras and a YAML file naming the space (as a user would set it up)."""
    twin = service.get("/twin")
    ids: dict[str, int] = twin["cameras"]
    space_id = service.get(f"/cameras/{next(iter(ids.values()))}")["space_id"]
    created = service.http.post(
        "/tokens", json={"name": "node", "scopes": ["ingest"], "camera_ids": list(ids.values())}
    )
    if created.status_code != 201:
        raise RuntimeError(f"POST /tokens answered {created.status_code}: {created.text}")
    config = folder / "node.yaml"
    config.write_text(
        f"space: {space_id}\ncameras:\n"
        + "".join(
            f"  - name: {name}\n    source: {service.api}/cameras/{camera_id}/stream.mjpg\n"
            for name, camera_id in ids.items()
        ),
        encoding="utf-8",
    )
    env = clean_env()
    env["INTSPACE_TOKEN"] = created.json()["token"]
    with (folder / "node.log").open("w") as out:
        return subprocess.Popen(
            [
                sys.executable,
                "-m",
                "server.cli",
                "node",
                "--config",
                str(config),
                "--api",
                service.api,
            ],
            cwd=REPO_ROOT,
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=out,
        )


@dataclass
class TruthPoller:
    """Polls GET /twin; keeps (sent, received, sim_time, x, y) of every answer."""

    service: Service
    rows: list[tuple[float, float, float, float, float]] = field(default_factory=list)

    def poll(self) -> float:
        """Ask once; return the twin's simulated time (NaN before its robot moves)."""
        sent = time.time()
        state = self.service.get("/twin")
        received = time.time()
        robot = state.get("robot")
        if robot is None:
            return float("nan")
        self.rows.append((sent, received, state["sim_time"], robot["x"], robot["y"]))
        return float(state["sim_time"])

    def steps(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Return each step seen: its simulated time (K,), the interval [lo, hi] (K, 2) its
        capture time lies in (Unix s), and the robot's true position (K, 2)."""
        rows = np.array(self.rows, dtype=np.float64).reshape(-1, 5)
        sim = rows[:, 2]
        first = np.flatnonzero(np.r_[True, np.diff(sim) > 0])
        # A step is stamped after the previous step's last answer was sent and before its own
        # first answer came back.
        lo = np.r_[-np.inf, rows[first[1:] - 1, 0]]
        hi = rows[first, 1]
        return sim[first], np.column_stack([lo, hi]), rows[first][:, 3:5]

    def truth_at(self, t: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Return the simulated time (N,) and true robot position (N, 2) of each capture time
        `t` (N,), NaN where no seen step's interval holds it."""
        sim, window, xy = self.steps()
        lo = window[:, 0] - _MATCH_SLACK_S
        hi = window[:, 1] + _MATCH_SLACK_S
        inside = (t[:, None] >= lo[None, :]) & (t[:, None] <= hi[None, :])
        one = inside.sum(axis=1) == 1
        k = np.argmax(inside, axis=1)
        out_sim = np.where(one, sim[k], np.nan)
        out_xy = np.where(one[:, None], xy[k], np.nan)
        return out_sim, out_xy


class PositionsListener:
    """A /ws/targets client in a thread: the arrival time (this machine's clock) and the robot
    target's observation time (its own `t`, the newest when several) of every positions
    message that holds a robot target."""

    def __init__(self, service: Service) -> None:
        url = service.api.replace("http://", "ws://") + "/ws/targets"
        self._ws = connect(url, additional_headers=HEADERS, open_timeout=10)
        self.messages: list[tuple[float, float]] = []
        self._thread = threading.Thread(target=self._run, name="ws", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            for raw in self._ws:
                arrived = time.time()
                message = json.loads(raw)
                robots = [
                    float(t["t"])
                    for t in message.get("targets", [])
                    if t["kind"] == "robot" and t.get("t") is not None
                ]
                if robots:
                    self.messages.append((arrived, max(robots)))
        except Exception:  # the socket closes when the listener or the service stops
            return

    def latency(self, stamps: NDArray[np.float64]) -> NDArray[np.float64]:
        """Return, per capture time in `stamps` (N,), the delay until the first message that
        holds the robot updated by an observation at least that recent (NaN when none
        came)."""
        got = np.array(self.messages, dtype=np.float64).reshape(-1, 2)
        if got.shape[0] == 0:
            return np.full(stamps.shape, np.nan)
        # The robot's observation time only grows, except when its target ends; a running
        # maximum makes "the first message at least as recent" a sorted search.
        newest = np.maximum.accumulate(got[:, 1])
        i = np.searchsorted(newest, stamps, side="left")
        ok = i < got.shape[0]
        out = np.full(stamps.shape, np.nan)
        out[ok] = got[i[ok], 0] - stamps[ok]
        return out

    def close(self) -> None:
        self._ws.close()
        self._thread.join(5)


@dataclass(frozen=True)
class Window:
    """The window of simulated time both paths are scored on, [start, start + seconds]."""

    start: float
    seconds: float
    abort: threading.Event = field(default_factory=threading.Event)

    @property
    def end(self) -> float:
        """Return the window's end (s of simulated time)."""
        return self.start + self.seconds


@dataclass(frozen=True)
class PathRun:
    """One path's figures over the scored window of simulated time."""

    detection: str
    window: tuple[float, float]
    steps: int  # twin steps seen in the window
    sim: NDArray[np.float64]  # (N,) s, the simulated time of each scored robot track point
    errors: NDArray[np.float64]  # (N,) m, its distance to the robot's true position
    latency: NDArray[np.float64]  # (N,) s, capture to WebSocket
    unmatched: int  # robot track points while it polled whose step the polling missed
    twin_rmse_m: float | None  # GET /twin robot_error_rms_m (the labelled robot only)
    cameras: dict[str, dict[str, Any]]  # name -> health (the node's path)
    posted: int | None  # detections the node posted
    late_frames: int | None  # camera frames the tracker refused as late (the node's count)
    healthy_s: float  # wall time from start to the service's first healthy answer
    first_robot_s: float  # ... to the first WebSocket message holding a robot
    seconds: float  # wall time of the run
    # Where the delay goes: the stages' p50/p95 as the service's tracker and the node report
    # them when they stop (server.services.tracking.FrameDelays, server.node.runner).
    stages: tuple[str, ...] = ()

    @property
    def rmse_m(self) -> float:
        """Return the robot's position RMSE (m) over the scored points."""
        return float(np.sqrt(np.mean(self.errors**2))) if self.errors.size else float("nan")

    @property
    def coverage(self) -> float:
        """Return the fraction of the window's steps with a robot track point."""
        return np.unique(self.sim).size / self.steps if self.steps else 0.0

    def latency_percentile(self, q: float) -> float:
        """Return the q-th percentile of the capture-to-WebSocket latency (s)."""
        ok = self.latency[np.isfinite(self.latency)]
        return float(np.percentile(ok, q)) if ok.size else float("nan")


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


def _robot_points(service: Service) -> NDArray[np.float64]:
    """Return every stored track point (t, x, y) of the robot's targets, in time order."""
    rows: list[list[float]] = []
    for target in service.get("/targets", kind="robot", state="all", limit=100)["items"]:
        track = service.get(f"/targets/{target['id']}/track", limit=10_000)["points"]
        rows += [[p["t"], p["xy"][0], p["xy"][1]] for p in track]
    points = np.array(rows, dtype=np.float64).reshape(-1, 3)
    return points[np.argsort(points[:, 0])]


def _stop_node(node: subprocess.Popen) -> None:
    if node.poll() is None:
        node.send_signal(signal.SIGINT)  # the node posts what it holds and says what it did
        try:
            node.wait(15)
        except subprocess.TimeoutExpired:
            node.kill()
            node.wait()


def _node_counts(log: str) -> tuple[int | None, int | None]:
    """Return (detections posted, camera frames too late to be tracked) from a node's log."""
    match = re.search(
        r"posted (\d+) detection\(s\) and \d+ empty frame\(s\); (\d+) camera frame\(s\) "
        r"came too late",
        log,
    )
    return (int(match[1]), int(match[2])) if match else (None, None)


def _stage_lines(log: str, *prefixes: str) -> list[str]:
    """Return the delays of the pipeline's stages that a log reports (lines after a prefix)."""
    out = []
    for line in log.splitlines():
        for prefix in prefixes:
            if prefix in line:
                out.append(prefix + line.split(prefix, 1)[1])
    return out


def run_path(
    detection: str,
    folder: Path,
    window: Window,
    *,
    seed: int = 0,
    tracker_latency_s: float | None = None,
    timeout_s: float | None = None,
) -> PathRun:
    """Run the service with the twin (detection "internal", or "external" with one node) until
    the twin's simulated time passes the end of `window`, and score the robot in it."""
    folder.mkdir(parents=True, exist_ok=True)
    began = time.monotonic()
    service = Service(folder, detection, seed, tracker_latency_s)
    node: subprocess.Popen | None = None
    listener: PositionsListener | None = None

    def node_log() -> str:
        return "" if node is None else "\nnode:\n" + (folder / "node.log").read_text()

    try:
        service.wait_healthy()
        healthy_s = time.monotonic() - began
        first_robot_s = float("nan")
        if detection == "external":
            node = start_node(service, folder)
        listener = PositionsListener(service)
        truth = TruthPoller(service)
        # A loaded machine runs the twin slower than real time: give it five times the window.
        limit = 120.0 + 5.0 * window.end if timeout_s is None else timeout_s
        deadline = time.monotonic() + limit
        while True:
            sim = truth.poll()
            if window.abort.is_set():
                raise RuntimeError(f"the {detection} path stopped: the other path failed")
            if time.monotonic() > deadline:
                raise RuntimeError(
                    f"the {detection} path did not reach the end of its window in {limit:g} s"
                    + node_log()
                )
            if node is not None and node.poll() is not None:
                raise RuntimeError("the node exited" + node_log())
            if listener.messages and first_robot_s != first_robot_s:
                first_robot_s = time.monotonic() - began
            if sim >= window.end:
                break
            time.sleep(_POLL_S)
        cameras: dict[str, dict[str, Any]] = {}
        posted = late = None
        if node is not None:
            for name, camera_id in service.get("/twin")["cameras"].items():
                cameras[name] = service.get(f"/cameras/{camera_id}")["health"]
            _stop_node(node)
            posted, late = _node_counts((folder / "node.log").read_text())
        # The live targets are written to the database twice a second: wait for the window's
        # last points.
        time.sleep(1.2)
        twin_rmse = service.get("/twin")["robot_error_rms_m"]
        points = _robot_points(service)
        sim_of, true_xy = truth.truth_at(points[:, 0])
        matched = np.isfinite(sim_of)
        scored = matched & (sim_of >= window.start) & (sim_of <= window.end)
        step_sim = truth.steps()[0]
        latency = listener.latency(points[scored, 0])
        listener.close()
        listener = None
        service.stop()  # the tracker reports its stages' delays as it stops
        logs = (folder / "serve.log").read_text()
        if node is not None:
            logs += (folder / "node.log").read_text()
        stages = _stage_lines(logs, "tracker: ", "frames: ", "uploads: ")
        return PathRun(
            detection=detection,
            window=(window.start, window.end),
            steps=int(np.count_nonzero((step_sim >= window.start) & (step_sim <= window.end))),
            sim=sim_of[scored],
            errors=np.linalg.norm(points[scored, 1:3] - true_xy[scored], axis=1),
            latency=latency,
            unmatched=int(np.count_nonzero(~matched & (points[:, 0] <= truth.rows[-1][1]))),
            twin_rmse_m=twin_rmse,
            cameras=cameras,
            posted=posted,
            late_frames=late,
            healthy_s=healthy_s,
            first_robot_s=first_robot_s,
            seconds=time.monotonic() - began,
            stages=tuple(stages),
        )
    except BaseException:
        window.abort.set()
        raise
    finally:
        if listener is not None:
            listener.close()
        if node is not None:
            _stop_node(node)
        service.stop()


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
