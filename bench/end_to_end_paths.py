"""One path of the end-to-end bench: the service with the twin, detection "internal" or
"external" (with one node), run until the twin's simulated time passes the scored window's end,
and the robot scored in that window (RMSE against the twin's truth, capture-to-WebSocket
latency, the node's counts and the stages' delays)."""

from __future__ import annotations

import subprocess
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bench.end_to_end_probes import PositionsListener, TruthPoller, robot_points
from bench.end_to_end_service import TwinService, node_counts, start_node, stop_node

# GET /twin every 40 ms: the twin's steps are 200 ms apart at its default 5 Hz, so each step's
# capture time is bracketed to a fraction of a step, and the service is barely loaded.
_POLL_S = 0.04
# The scored window starts this far into the simulation (s): the node connects to the streams
# while the twin learns its cameras' backgrounds, before its first step, so by then it is
# reading them.
WINDOW_START_S = 3.0


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
    service = TwinService(folder, detection, seed, tracker_latency_s)
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
            stop_node(node)
            posted, late = node_counts((folder / "node.log").read_text())
        # The live targets are written to the database twice a second: wait for the window's
        # last points.
        time.sleep(1.2)
        twin_rmse = service.get("/twin")["robot_error_rms_m"]
        points = robot_points(service)
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
            stop_node(node)
        service.stop()
