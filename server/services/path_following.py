"""Following a planned path (spec 03): its follow tasks.

A follow task runs the closed loop of the twin's `path-following` scenario
(core.sim.spot_following.simulate_following) for one law on the path's trajectory, in a
background thread: the twin's true projector (its seeded mounting error) draws the spot from
the commanded angles, the robot's floor camera sees it at 15 Hz with 100 ms latency (every
frame rendered from the robot's true pose and the spot detected in it), and the
error is the distance between the robot's control point and the true spot (scored against the
twin). The row carries the status, the progress and the series so far while it runs (written
every `_HEARTBEAT_S`: the tracking error, the robot's true pose and the true spot, 5 Hz), then
the metrics and the whole series. The task is a job of server.services.jobs, held under a
lease its process renews: a task whose lease expired (the service was stopped) reads as
interrupted.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from datetime import datetime
from typing import Any

import numpy as np
from sqlalchemy import or_
from sqlalchemy.orm import Session, sessionmaker

from core.navigation import Limits, SpotFollower
from core.sim import Scene
from core.sim.floor_camera import calibrate_floor_camera
from core.sim.projector import twin_projector
from core.sim.render import Renderer
from core.sim.spot_following import (
    CAMERA_LATENCY,
    CAMERA_RATE,
    CONTROL_DT,
    make_laws,
    simulate_following,
    start_pose,
)
from server.db.models import PlannedPath
from server.schemas.paths import FollowRead, FollowResult
from server.services.jobs import (
    JobCancelled,
    JobEngine,
    JobTable,
    Lease,
    LeasePolicy,
    claim,
    lease_expired,
)
from server.services.paths import PathProblem, draw, model_from

log = logging.getLogger(__name__)

SERIES_DT = 0.2  # s between the stored error series' samples
MAX_FOLLOWS = 2  # follow tasks running at once in one service process
_HEARTBEAT_S = 0.5  # s between the writes of a running follow's progress and series
_STALE_S = 30.0  # s a follow task's lease lasts unless renewed
_LEASE_HEARTBEAT_S = 5.0

LAWS = ("state_feedback", "adaptive", "proportional")

# A follow task is claimed by the process that starts it (a path is followed by one task at a
# time) and given up as interrupted when that process stops renewing its lease.
FOLLOWS = JobTable(
    model=PlannedPath,
    status=PlannedPath.follow_status,
    running="running",
    held=("running",),
    expired_reason="the service running it stopped before it finished",
    expired_status="interrupted",
    error="follow_error",
    started="follow_started_at",
    finished="follow_finished_at",
)
FOLLOW_LEASES = LeasePolicy(lease_s=_STALE_S, heartbeat_s=_LEASE_HEARTBEAT_S, max_attempts=1)


def claim_follow(
    session: Session, path_id: int, owner: str, policy: LeasePolicy, law: str, seed: int
) -> bool:
    """Start a follow task of path `path_id` with `law` and `seed` under a lease held by
    `owner`, unless one runs (its lease not expired); return whether it did. Of two services
    starting the same path at once, one wins (server.services.jobs.claim)."""
    return claim(
        session,
        FOLLOWS,
        path_id,
        owner,
        policy,
        or_(PlannedPath.follow_status != "running", FOLLOWS.expired()),
        follow_law=law,
        follow_seed=seed,
        follow_progress=0.0,
        follow_result=None,
        follow_series=None,
        follow_error=None,
        follow_finished_at=None,
    )


def follow_view(row: PlannedPath, now: datetime | None = None) -> FollowRead:
    """Return the follow task's state as the API shows it; a running task whose lease has
    expired (its service stopped) reads as interrupted."""
    status = row.follow_status
    if status == "running" and lease_expired(row, now):
        status = "interrupted"
    result = row.follow_result
    return FollowRead(
        status=status,
        law=row.follow_law,
        seed=row.follow_seed,
        progress=row.follow_progress,
        result=None if result is None else FollowResult.model_validate(result),
        series=row.follow_series,
        error=row.follow_error,
        started_at=row.follow_started_at,
        finished_at=row.follow_finished_at,
    )


def _law(name: str, limits: Limits) -> SpotFollower:
    for law in make_laws(limits):
        if law.name == name:
            return law
    raise PathProblem(422, "law", f"unknown law {name!r}; one of {', '.join(LAWS)}")


class FollowTasks(JobEngine):
    """The follow tasks this service process runs, each in its own thread, under a lease
    (server.services.jobs): at most `max_running` at once."""

    def __init__(
        self,
        factory: sessionmaker[Session],
        max_running: int = MAX_FOLLOWS,
        policy: LeasePolicy = FOLLOW_LEASES,
    ) -> None:
        self._starting = threading.Lock()
        self._scenes: dict[int, Scene] = {}
        super().__init__(factory, FOLLOWS, self._run, max_running, policy, name="follow-path")

    def start(self, session: Session, row: PlannedPath, scene: Scene | None, law: str, seed: int):
        """Start following `row` with `law` on the twin; the row says it runs when this
        returns. Raises PathProblem (409) when the path has no trajectory, the space is not the
        twin's home, the path is being followed already or too many tasks run."""
        if row.trajectory is None or row.projector_model is None:
            raise PathProblem(
                409,
                "path_id",
                f"path {row.id} has no projector trajectory to follow; plan it with a projector_id",
            )
        if scene is None:
            raise PathProblem(
                409,
                "path_id",
                f"path {row.id} is not in the digital twin's home: the follow "
                "task runs on the twin only",
            )
        if scene.robot is None:
            raise PathProblem(409, "path_id", f"the twin scene {scene.name!r} has no robot")
        if follow_view(row).status == "running":
            raise PathProblem(409, "path_id", f"path {row.id} is being followed already")
        with self._starting:
            alive = self.held()
            if len(alive) >= self.workers:
                raise PathProblem(
                    409,
                    "path_id",
                    f"{len(alive)} follow tasks are running (paths "
                    f"{', '.join(map(str, alive))}); start this one when one has ended",
                )
            if not claim_follow(session, row.id, self.owner, self.policy, law, seed):
                raise PathProblem(409, "path_id", f"path {row.id} is being followed already")
            self._scenes[row.id] = scene
            self.hold(row.id)

    def _run(self, lease: Lease) -> str | None:
        path_id = lease.job_id
        scene = self._scenes.pop(path_id)
        outcome: dict[str, Any]
        try:
            result, series = self._simulate(lease, scene)
            outcome = {
                "follow_status": "succeeded",
                "follow_progress": 1.0,
                "follow_result": result.model_dump(),
                "follow_series": series,
            }
        except JobCancelled:  # deleted while it ran, or its service is stopping
            return None
        except Exception as exc:  # the task's own failure, reported on its row
            log.exception("follow task of path %d failed", path_id)
            outcome = {"follow_status": "failed", "follow_error": f"{type(exc).__name__}: {exc}"}
        with self._factory() as session:
            return str(outcome["follow_status"]) if lease.finish(session, **outcome) else None

    def _simulate(self, lease: Lease, scene: Scene) -> tuple[FollowResult, dict[str, list[float]]]:
        with self._factory() as session:
            row = session.get(PlannedPath, lease.job_id)
            if row is None or row.projector_model is None or row.spot_speed_mps is None:
                raise LookupError(f"path {lease.job_id} has no projector trajectory any more")
            model = model_from(row.projector_model)
            points = np.asarray(row.points, dtype=np.float64)
            speed = float(row.spot_speed_mps)
            law_name, seed = str(row.follow_law), int(row.follow_seed or 0)
        robot = scene.robot
        assert robot is not None  # checked by start()
        traj = draw(model, points, speed)
        truth = twin_projector(scene, seed)
        renderer = Renderer(scene, supersample=1)
        plane = calibrate_floor_camera(np.random.default_rng([seed, 7]), renderer)
        law = _law(law_name, Limits(robot.limits.max_speed, robot.limits.max_turn_rate))

        def report(progress: float, series: dict[str, list[float]]) -> None:
            lease.write(follow_progress=progress, follow_series=series)

        live = LiveSeries(traj.duration, report)
        run = simulate_following(
            law,
            traj,
            truth,
            plane,
            start_pose(traj),
            scene,
            seed,
            on_step=live.step,
            renderer=renderer,
        )
        drawn = truth.spot(traj.q)
        steady = run.steady
        result = FollowResult(
            rms_m=run.rms,
            max_m=float(run.error.max()),
            steady_m=None if math.isnan(steady) else steady,
            finish_s=run.finished_s,
            lost_events=run.lost_events,
            duration_s=traj.duration,
            drawing_error_max_m=float(np.max(np.linalg.norm(drawn - traj.spot, axis=1))),
            camera_hz=CAMERA_RATE,
            latency_s=CAMERA_LATENCY,
        )
        return result, series_of(run.time, run.error, run.pose, run.spot)

    def shutdown(self, reason: str = "the service stopped during it") -> int:
        """Stop: the running follows end at their next report, and every one this process
        held is marked interrupted with `reason`; return how many."""
        return super().shutdown(reason)


SERIES_STEP = max(1, round(SERIES_DT / CONTROL_DT))  # control steps between samples


def series_of(
    t: np.ndarray, error: np.ndarray, pose: np.ndarray, spot: np.ndarray, step: int = SERIES_STEP
) -> dict[str, list[float]]:
    """Return the stored series of a run's samples (every `step`-th from the first): t (s),
    error_m (m), the robot's true pose x, y (m), theta (rad), and the true spot spot_x, spot_y
    (m); pose (N, 3), spot (N, 2)."""
    k = slice(None, None, step)
    pose, spot = np.asarray(pose).reshape(-1, 3)[k], np.asarray(spot).reshape(-1, 2)[k]
    return {
        "t": np.round(np.asarray(t)[k], 3).tolist(),
        "error_m": np.round(np.asarray(error)[k], 5).tolist(),
        "x": np.round(pose[:, 0], 4).tolist(),
        "y": np.round(pose[:, 1], 4).tolist(),
        "theta": np.round(pose[:, 2], 4).tolist(),
        "spot_x": np.round(spot[:, 0], 4).tolist(),
        "spot_y": np.round(spot[:, 1], 4).tolist(),
    }


class LiveSeries:
    """The `on_step` of a follow run (core.sim.spot_following.simulate_following): keeps
    the samples the stored series will hold and hands the series so far, with the progress
    (simulated time over the trajectory's `duration`, at most 1), to `report` at most every
    `every_s` seconds of wall time (default: the heartbeat's), so that `GET /paths/{id}` shows
    the run as it goes."""

    def __init__(
        self,
        duration: float,
        report: Callable[[float, dict[str, list[float]]], None],
        every_s: float | None = None,
    ) -> None:
        self._duration = duration
        self._report = report
        self._every = _HEARTBEAT_S if every_s is None else every_s
        self._last = time.monotonic()
        self._k = 0
        self._t: list[float] = []
        self._e: list[float] = []
        self._pose: list[np.ndarray] = []
        self._spot: list[np.ndarray] = []

    def step(self, t: float, pose: np.ndarray, spot: np.ndarray, error: float) -> None:
        """Record one control step (every SERIES_STEP-th is kept); report when it is time."""
        if self._k % SERIES_STEP == 0:
            self._t.append(t)
            self._e.append(error)
            self._pose.append(pose.copy())
            self._spot.append(spot.copy())
        self._k += 1
        now = time.monotonic()
        if now - self._last >= self._every:
            self._last = now
            progress = min(1.0, t / self._duration) if self._duration > 0 else 1.0
            self._report(progress, self.series())

    def series(self) -> dict[str, list[float]]:
        """Return the series so far (series_of's keys)."""
        return series_of(
            np.asarray(self._t),
            np.asarray(self._e),
            np.asarray(self._pose),
            np.asarray(self._spot),
            step=1,
        )
