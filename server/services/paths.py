"""Planned paths and their follow tasks (spec 03).

Planning. The space's floor plan is the digital twin's scene when the space is the twin's home
(walls with doors, furniture: server.services.floor_plan decides); any other space has only
its rooms in the registry, so its plan is the union of the room polygons. The plan is rasterised by
core.navigation.occupancy_grid, inflated by the robot's radius plus the planning margin of the
twin's `path-following` scenario, and searched by core.navigation.plan_path. With a projector
the path is turned into the joint trajectory that draws it (core.projector.project_path, the
scenario's spot acceleration and corner fillets), using the projector's registered mount pose
as the pan-tilt base pose T_world_base and the tilt offset of its applied calibration; a
projector without a pose is uncalibrated.

Following. A follow task runs the closed loop of the twin's `path-following` scenario
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

Projector calibration runs, which set the registered pose this module reads, are
server.services.calibration.projector.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime
from typing import Any

import numpy as np
from sqlalchemy import or_, select
from sqlalchemy.orm import Session, sessionmaker

from core.errors import IntspaceError
from core.geometry.polygon import inside_polygon
from core.navigation import (
    Limits,
    NoRoute,
    OccupancyGrid,
    SpotFollower,
    occupancy_grid,
    plan_path,
    wall_spans,
)
from core.projector import JointTrajectory, PanTiltProjector, project_path
from core.sim import Scene
from core.sim.floor_camera import calibrate_floor_camera
from core.sim.projector import nominal_projector, twin_projector
from core.sim.render import Renderer
from core.sim.spot_following import (
    CAMERA_LATENCY,
    CAMERA_RATE,
    CONTROL_DT,
    CORNER_RADIUS,
    PLAN_MARGIN,
    PLAN_RESOLUTION,
    SPOT_ACCELERATION,
    SPOT_SPEED,
    make_laws,
    simulate_following,
    start_pose,
)
from server.db.models import (
    PlannedPath,
    Projector,
    Robot,
    Room,
)
from server.schemas.paths import (
    FloorPlanDrawing,
    FollowRead,
    FollowResult,
    FurnitureRead,
    JointTrajectoryRead,
    RoomOutlineRead,
    WallSpanRead,
)
from server.services.calibration.projector import latest_calibration
from server.services.jobs import (
    JobCancelled,
    JobEngine,
    JobTable,
    Lease,
    LeasePolicy,
    claim,
    lease_expired,
)

log = logging.getLogger(__name__)

DEFAULT_ROBOT_RADIUS = 0.2  # m, when the space has no robot with a base radius
# Grids beyond this many cells get coarser cells, so that planning stays interactive (spec 03
# budgets 50 ms for 400 x 300 cells; a 40 x 30 m floor at 5 cm would be 480k).
MAX_GRID_CELLS = 250_000
TRAJECTORY_DT = 0.05  # s between the stored trajectory's samples
SERIES_DT = 0.2  # s between the stored error series' samples
MAX_FOLLOWS = 2  # follow tasks running at once in one service process
_HEARTBEAT_S = 0.5  # s between the writes of a running follow's progress and series
_STALE_S = 30.0  # s a follow task's lease lasts unless renewed
_LEASE_HEARTBEAT_S = 5.0

LAWS = ("state_feedback", "adaptive", "proportional")


class PathProblem(Exception):
    """A request the service refuses: HTTP `status`, the request `field` at fault, `reason`."""

    def __init__(self, status: int, field: str, reason: str) -> None:
        super().__init__(reason)
        self.status = status
        self.field = field


@dataclass(frozen=True)
class _RoomOutline:
    name: str
    polygon: Sequence[tuple[float, float]]


@dataclass(frozen=True)
class RoomsPlan:
    """A floor plan made of room polygons only (core.navigation.FloorPlan)."""

    rooms: Sequence[_RoomOutline]
    walls: Sequence[Any] = ()
    furniture: Sequence[Any] = ()


@dataclass(frozen=True)
class FloorPlanChoice:
    """The plan to plan on, how to name it, and the twin scene when it is the twin's home."""

    plan: Any
    label: str
    scene: Scene | None = field(default=None, repr=False)


def floor_plan_of(session: Session, space_id: int, scene: Scene | None) -> FloorPlanChoice:
    """Return the space's floor plan: `scene` (the twin's home, when the space is it) or its
    registered rooms. Raises PathProblem (409) when the space has no room."""
    if scene is not None:
        return FloorPlanChoice(scene, f"twin scene {scene.name!r}", scene)
    polygons = session.execute(
        select(Room.name, Room.polygon).where(Room.space_id == space_id).order_by(Room.id)
    ).all()
    if not polygons:
        raise PathProblem(
            409, "space_id", f"space {space_id} has no rooms: register its room polygons first"
        )
    rooms = [_RoomOutline(n, [(float(x), float(y)) for x, y in p]) for n, p in polygons]
    return FloorPlanChoice(RoomsPlan(rooms), "registered rooms (no walls or furniture)")


def plan_drawing(choice: FloorPlanChoice) -> FloorPlanDrawing:
    """Return the floor plan as drawn on a map: room polygons, solid wall spans (between their
    doors) with their thickness, and furniture footprints (4 corners), world metres."""
    plan = choice.plan
    walls = [
        WallSpanRead(start=a.tolist(), end=b.tolist(), thickness=float(w.thickness))
        for w in plan.walls
        for a, b in wall_spans(w)
    ]
    furniture = []
    for f in plan.furniture:
        c, s = math.cos(f.yaw), math.sin(f.yaw)
        half = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * np.asarray(f.size[:2]) / 2
        corners = np.asarray(f.centre) + half @ np.array([[c, s], [-s, c]])
        furniture.append(FurnitureRead(name=getattr(f, "name", ""), footprint=corners.tolist()))
    return FloorPlanDrawing(
        floor_plan=choice.label,
        rooms=[
            RoomOutlineRead(name=r.name, polygon=[[float(x), float(y)] for x, y in r.polygon])
            for r in plan.rooms
        ],
        walls=walls,
        furniture=furniture,
    )


def robot_radius_of(session: Session, space_id: int) -> float:
    """Return the base radius (m) of the space's first robot that has one, else the default."""
    models = session.scalars(
        select(Robot.kinematic_model).where(Robot.space_id == space_id).order_by(Robot.id)
    ).all()
    for model in models:
        r = model.get("base_radius") if isinstance(model, dict) else None
        if isinstance(r, (int, float)) and math.isfinite(r) and 0 <= r <= 2:
            return float(r)
    return DEFAULT_ROBOT_RADIUS


def _grid(plan: Any, radius: float) -> OccupancyGrid:
    corners = np.array([p for r in plan.rooms for p in r.polygon], dtype=np.float64)
    area = float(np.prod(corners.max(0) - corners.min(0)))
    resolution = max(PLAN_RESOLUTION, math.sqrt(area / MAX_GRID_CELLS))
    return occupancy_grid(plan, radius + PLAN_MARGIN, resolution)


def _check_endpoint(plan: Any, grid: OccupancyGrid, p: np.ndarray, name: str, clear: float):
    inside = any(
        inside_polygon(p[None], np.asarray(r.polygon, dtype=np.float64))[0] for r in plan.rooms
    )
    if not inside:
        raise PathProblem(
            422,
            name,
            f"the {name} ({p[0]:.3f}, {p[1]:.3f}) m is outside the floor plan (no "
            "room contains it)",
        )
    j, i = np.floor((p - np.asarray(grid.origin)) / grid.resolution).astype(int)
    rows, cols = grid.free.shape
    if not (0 <= i < rows and 0 <= j < cols and grid.free[i, j]):
        raise PathProblem(
            422,
            name,
            f"the {name} ({p[0]:.3f}, {p[1]:.3f}) m lies in a wall or an obstacle, "
            f"or within {clear:.2f} m of one (the robot's radius plus the planning margin); "
            "move it into free floor",
        )


def tilt_offset_of(session: Session, row: Projector) -> float:
    """Return the tilt offset (rad) of the projector's latest applied calibration when its pose
    is still the registered one (a pose entered by hand since has no known offset), else 0."""
    latest = latest_calibration(session, row.id)
    if latest is None or row.T_world_projector is None:
        return 0.0
    same = np.allclose(latest.T_world_projector, row.T_world_projector, rtol=0.0, atol=1e-12)
    return float(latest.tilt_offset) if same else 0.0


def projector_model(
    session: Session, row: Projector, space_id: int, scene: Scene | None
) -> PanTiltProjector:
    """Return the pan-tilt model of a registered projector: its pose as T_world_base, the tilt
    offset of its applied calibration, the joint limits of the twin's projector in the twin's
    home (else the model's defaults). Raises PathProblem: a projector of another space (422)
    or without a pose (409, uncalibrated)."""
    if row.space_id != space_id:
        raise PathProblem(
            422,
            "projector_id",
            f"projector {row.id} is not in space {space_id} (its space: {row.space_id})",
        )
    if row.T_world_projector is None:
        raise PathProblem(
            409,
            "projector_id",
            f"projector {row.id} ({row.name}) is uncalibrated: it has no "
            "pose T_world_projector; run a projector calibration or enter its mount pose",
        )
    theta = np.array([0.0, tilt_offset_of(session, row)])
    try:
        if scene is not None and scene.projector is not None:
            model = nominal_projector(scene).with_pose(row.T_world_projector)
        else:
            model = PanTiltProjector(np.asarray(row.T_world_projector, dtype=np.float64))
        return replace(model, theta=theta)
    except IntspaceError as exc:
        raise PathProblem(
            422, "projector_id", f"projector {row.id}'s pose is not a pan-tilt mount: {exc}"
        ) from exc


def _model_dict(model: PanTiltProjector) -> dict[str, Any]:
    return {
        "T_world_base": model.T_world_base.tolist(),
        "theta": model.theta.tolist(),
        "pan_limits": list(model.pan_limits),
        "tilt_limits": list(model.tilt_limits),
        "max_rate": list(model.max_rate),
        "max_acceleration": list(model.max_acceleration),
    }


def _model_from(d: dict[str, Any]) -> PanTiltProjector:
    return PanTiltProjector(
        np.asarray(d["T_world_base"], dtype=np.float64),
        theta=np.asarray(d.get("theta", (0.0, 0.0)), dtype=np.float64),
        pan_limits=tuple(d["pan_limits"]),
        tilt_limits=tuple(d["tilt_limits"]),
        max_rate=tuple(d["max_rate"]),
        max_acceleration=tuple(d["max_acceleration"]),
    )


def draw(model: PanTiltProjector, points: np.ndarray, spot_speed: float) -> JointTrajectory:
    """Return the joint trajectory drawing `points` at `spot_speed` (the scenario's spot
    acceleration and corner fillets)."""
    return project_path(
        model,
        points,
        spot_speed,
        spot_acceleration=SPOT_ACCELERATION,
        corner_radius=CORNER_RADIUS,
    )


def _trajectory_read(traj: JointTrajectory) -> JointTrajectoryRead:
    t = np.append(np.arange(0.0, traj.duration, TRAJECTORY_DT), traj.duration)
    q, spot = traj.at(t)
    return JointTrajectoryRead(
        dt_s=TRAJECTORY_DT,
        duration_s=traj.duration,
        t=np.round(t, 4).tolist(),
        q=np.round(q, 8).tolist(),
        spot=np.round(spot, 6).tolist(),
    )


def plan(
    session: Session,
    space_id: int,
    choice: FloorPlanChoice,
    start: Sequence[float],
    goal: Sequence[float],
    *,
    robot_radius: float,
    projector: Projector | None = None,
    spot_speed: float = SPOT_SPEED,
) -> PlannedPath:
    """Plan, draw (with a projector) and store a path; return its row.

    Raises PathProblem naming the field at fault: start or goal outside the plan or in an
    obstacle, no route (422), the projector uncalibrated (409) or unable to reach the path
    (422)."""
    model = (
        None if projector is None else projector_model(session, projector, space_id, choice.scene)
    )
    grid = _grid(choice.plan, robot_radius)
    s, g = np.asarray(start, dtype=np.float64), np.asarray(goal, dtype=np.float64)
    clear = robot_radius + PLAN_MARGIN
    _check_endpoint(choice.plan, grid, s, "start", clear)
    _check_endpoint(choice.plan, grid, g, "goal", clear)
    try:
        points = plan_path(grid.free, s, g, resolution=grid.resolution, origin=grid.origin)
    except NoRoute as exc:
        raise PathProblem(422, "goal", str(exc)) from exc
    length = float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1)))
    trajectory = None
    if model is not None and projector is not None:
        if length < 1e-6:
            raise PathProblem(422, "goal", "the start and the goal coincide: nothing to draw")
        try:
            trajectory = _trajectory_read(draw(model, points, spot_speed))
        except IntspaceError as exc:
            raise PathProblem(
                422,
                "projector_id",
                f"projector {projector.id} cannot draw this path: {type(exc).__name__}: {exc}",
            ) from exc
    row = PlannedPath(
        space_id=space_id,
        projector_id=None if projector is None else projector.id,
        start=s.tolist(),
        goal=g.tolist(),
        points=points.tolist(),
        length_m=length,
        robot_radius_m=robot_radius,
        resolution_m=grid.resolution,
        floor_plan=choice.label,
        spot_speed_mps=None if model is None else spot_speed,
        projector_model=None if model is None else _model_dict(model),
        trajectory=None if trajectory is None else trajectory.model_dump(),
        follow_status="idle",
    )
    session.add(row)
    session.commit()
    return row


# --------------------------------------------------------------------------------------------
# Follow tasks


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
            model = _model_from(row.projector_model)
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
