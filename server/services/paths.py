"""Planned paths (spec 03); following them is server.services.path_following.

Planning. The space's floor plan is the digital twin's scene when the space is the twin's home
(walls with doors, furniture: server.services.floor_plan decides); any other space has only
its rooms in the registry, so its plan is the union of the room polygons. The plan is rasterised by
core.navigation.occupancy_grid, inflated by the robot's radius plus the planning margin of the
twin's `path-following` scenario, and searched by core.navigation.plan_path. With a projector
the path is turned into the joint trajectory that draws it (core.projector.project_path, the
scenario's spot acceleration and corner fillets), using the projector's registered mount pose
as the pan-tilt base pose T_world_base and the tilt offset of its applied calibration; a
projector without a pose is uncalibrated.

Projector calibration runs, which set the registered pose this module reads, are
server.services.calibration.projector.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from core.errors import IntspaceError
from core.geometry.polygon import inside_polygon
from core.navigation import (
    NoRoute,
    OccupancyGrid,
    occupancy_grid,
    plan_path,
    wall_spans,
)
from core.projector import JointTrajectory, PanTiltProjector, project_path
from core.sim import Scene
from core.sim.projector import nominal_projector
from core.sim.spot_following import (
    CORNER_RADIUS,
    PLAN_MARGIN,
    PLAN_RESOLUTION,
    SPOT_ACCELERATION,
    SPOT_SPEED,
)
from server.db.models import (
    PlannedPath,
    Projector,
    Robot,
    Room,
)
from server.schemas.paths import (
    FloorPlanDrawing,
    FurnitureRead,
    JointTrajectoryRead,
    RoomOutlineRead,
    WallSpanRead,
)
from server.services.calibration.projector import latest_calibration

log = logging.getLogger(__name__)

DEFAULT_ROBOT_RADIUS = 0.2  # m, when the space has no robot with a base radius
# Grids beyond this many cells get coarser cells, so that planning stays interactive (spec 03
# budgets 50 ms for 400 x 300 cells; a 40 x 30 m floor at 5 cm would be 480k).
MAX_GRID_CELLS = 250_000
TRAJECTORY_DT = 0.05  # s between the stored trajectory's samples


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


def model_from(d: dict[str, Any]) -> PanTiltProjector:
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
