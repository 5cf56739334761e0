"""Paths: plan a path on a space's floor plan, draw it with a projector, follow it on the twin.

`POST /paths` plans (core.navigation) and, with a projector, returns the joint trajectory that
draws it (core.projector); `POST /paths/{id}/follow` starts the follow task on the digital
twin, whose status, progress, metrics and series (tracking error, robot pose, spot)
`GET /paths/{id}` returns, the series so far while the task runs (poll it).
`GET /projectors/{id}/calibrations` lists a projector's history, beside the paths it draws.
server.services.paths (planning) and server.services.path_following (follow tasks) have the
rules.
"""

from __future__ import annotations

import logging
from typing import Annotated

from fastapi import APIRouter, Path, Query, status
from sqlalchemy import select

from core.sim.spot_following import PLAN_MARGIN
from server.api._crud import get_or_404, page_of, paginate
from server.api.deps import (
    FollowTasksDep,
    PageDep,
    ReadAccess,
    SceneDep,
    SessionDep,
    SettingsDep,
    TwinDep,
    WriteAccess,
)
from server.api.errors import PROBLEM_RESPONSES, FieldProblem
from server.db.models import PlannedPath, Projector, ProjectorCalibration, Space
from server.scene import ProjectorEntry
from server.schemas.common import MAX_ID, Page
from server.schemas.paths import (
    FloorPlanRead,
    FollowCreate,
    PathCreate,
    PathRead,
    PathSummary,
    ProjectorCalibrationRead,
)
from server.services import paths as service
from server.services.floor_plan import twin_scene_of
from server.services.path_following import follow_view
from server.services.scene_sync import SceneSync

log = logging.getLogger(__name__)

# No prefix: the projectors' calibration history lives here too, beside the runs that make it.
router = APIRouter(tags=["paths"], responses=PROBLEM_RESPONSES)
PathId = Annotated[int, Path(ge=1, le=MAX_ID)]


def _refused(exc: service.PathProblem, location: str = "body") -> FieldProblem:
    return FieldProblem(exc.status, exc.field, str(exc), location)


def path_read(row: PlannedPath) -> PathRead:
    """Return the API view of a path row."""
    view = {
        "id": row.id,
        "space_id": row.space_id,
        "projector_id": row.projector_id,
        "start": row.start,
        "goal": row.goal,
        "points": row.points,
        "length_m": row.length_m,
        "robot_radius_m": row.robot_radius_m,
        "resolution_m": row.resolution_m,
        "floor_plan": row.floor_plan,
        "spot_speed_mps": row.spot_speed_mps,
        "projector_model": row.projector_model,
        "trajectory": row.trajectory,
        "follow": follow_view(row),
        "created_at": row.created_at,
    }
    return PathRead.model_validate(view)


@router.get("/paths", response_model=Page[PathSummary], dependencies=[ReadAccess])
def list_paths(
    session: SessionDep,
    page: PageDep,
    space_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
):
    """Return a page of paths (newest last), optionally of one space, without their
    trajectories and error series."""
    stmt = select(PlannedPath).order_by(PlannedPath.id)
    if space_id is not None:
        stmt = stmt.where(PlannedPath.space_id == space_id)
    return paginate(session, stmt, page)


@router.get("/paths/floor-plan", dependencies=[ReadAccess])
def get_floor_plan(
    twin: TwinDep,
    session: SessionDep,
    space_id: Annotated[int, Query(ge=1, le=MAX_ID)],
) -> FloorPlanRead:
    """Return the floor plan paths are planned on in this space: its rooms, the solid spans of
    its walls and its furniture footprints (the twin's home has walls and furniture; another
    space only its rooms), with the clearance the planner keeps (robot radius + margin, m)."""
    if session.get(Space, space_id) is None:
        raise FieldProblem(404, "space_id", f"no space with id {space_id}", "query")
    try:
        choice = service.floor_plan_of(session, space_id, twin_scene_of(twin, session, space_id))
    except service.PathProblem as exc:
        raise _refused(exc, "query") from exc
    radius = service.robot_radius_of(session, space_id)
    drawing = service.plan_drawing(choice)
    return FloorPlanRead(
        space_id=space_id,
        floor_plan=drawing.floor_plan,
        rooms=drawing.rooms,
        walls=drawing.walls,
        furniture=drawing.furniture,
        robot_radius_m=radius,
        clearance_m=radius + PLAN_MARGIN,
    )


@router.post(
    "/paths",
    response_model=PathRead,
    status_code=status.HTTP_201_CREATED,
    dependencies=[WriteAccess],
)
def create_path(body: PathCreate, twin: TwinDep, scene: SceneDep, session: SessionDep):
    """Plan a path from `start` to `goal` on the space's floor plan (the twin's walls and
    furniture in the twin's home, else the registered rooms), keeping the robot's radius plus
    5 cm from every obstacle; with `projector_id`, also the projector's joint trajectory drawing
    it at `spot_speed`. 422 names the field at fault: a start or goal outside the plan or in an
    obstacle, no route, a path the projector cannot reach; 409 an uncalibrated projector."""
    if session.get(Space, body.space_id) is None:
        raise FieldProblem(422, "space_id", f"no space with id {body.space_id}")
    projector = None
    if body.projector_id is not None:
        projector = session.get(Projector, body.projector_id)
        if projector is None:
            raise FieldProblem(422, "projector_id", f"no projector with id {body.projector_id}")
    try:
        choice = service.floor_plan_of(
            session, body.space_id, twin_scene_of(twin, session, body.space_id)
        )
        radius = (
            body.robot_radius
            if body.robot_radius is not None
            else service.robot_radius_of(session, body.space_id)
        )
        row = service.plan(
            session,
            body.space_id,
            choice,
            body.start,
            body.goal,
            robot_radius=radius,
            projector=projector,
            spot_speed=body.spot_speed,
        )
    except service.PathProblem as exc:
        raise _refused(exc) from exc
    _show_in_scene(scene, row, projector)
    return path_read(row)


def _show_in_scene(sync: SceneSync, row: PlannedPath, projector: Projector | None) -> None:
    """Draw the new path in the live 3D scene, with the projector that draws it (its mount and
    its beam on the path's first spot); a scene failure never fails the request."""
    scene = sync.scene
    if scene is None:
        return
    try:
        scene.set_planned_path(row.points)
        if projector is not None and row.projector_model is not None:
            spot = row.trajectory["spot"][0] if row.trajectory else None
            scene.set_projector(
                ProjectorEntry(projector.name, row.projector_model["T_world_base"], spot)
            )
    except Exception:
        log.exception("drawing path %d in the 3D scene failed", row.id)


@router.get("/paths/{path_id}", response_model=PathRead, dependencies=[ReadAccess])
def get_path(path_id: PathId, session: SessionDep):
    """Return one path with its trajectory and its follow task (status, progress and the series
    so far while it runs, renewed every 0.5 s; the metrics and the whole series once it
    ended)."""
    return path_read(get_or_404(session, PlannedPath, path_id, "path"))


@router.post(
    "/paths/{path_id}/follow",
    response_model=PathRead,
    status_code=status.HTTP_202_ACCEPTED,
    dependencies=[WriteAccess],
)
def follow_path(
    path_id: PathId,
    session: SessionDep,
    body: FollowCreate,
    tasks: FollowTasksDep,
    twin: TwinDep,
    settings: SettingsDep,
):
    """Start following the path on the digital twin with the chosen law: the twin's projector
    draws the spot, the robot's floor camera (15 Hz, 100 ms latency) sees it and the law steers
    the robot onto it. Answers at once; poll `GET /paths/{id}` for the status, the progress, the
    series so far (tracking error, robot pose, spot) and, at the end, the metrics. 409 when the
    path has no projector trajectory, is not in the twin's home, or is being followed
    already."""
    row = get_or_404(session, PlannedPath, path_id, "path")
    seed = body.seed if body.seed is not None else settings.twin_seed
    try:
        tasks.start(session, row, twin_scene_of(twin, session, row.space_id), body.law, seed)
    except service.PathProblem as exc:
        raise _refused(exc, "path" if exc.field == "path_id" else "body") from exc
    session.refresh(row)
    return path_read(row)


@router.delete(
    "/paths/{path_id}", status_code=status.HTTP_204_NO_CONTENT, dependencies=[WriteAccess]
)
def delete_path(path_id: PathId, session: SessionDep) -> None:
    """Delete a path (a follow task still running finishes without a row to write to)."""
    session.delete(get_or_404(session, PlannedPath, path_id, "path"))
    session.commit()


# --------------------------------------------------------------------------------------------
# A projector's calibration history (its runs: server.services.calibration.projector)


@router.get(
    "/projectors/{projector_id}/calibrations",
    response_model=Page[ProjectorCalibrationRead],
    tags=["projectors"],
    dependencies=[ReadAccess],
)
def list_projector_calibrations(
    projector_id: Annotated[int, Path(ge=1, le=MAX_ID)], session: SessionDep, page: PageDep
):
    """Return the projector's calibration history, newest first."""
    get_or_404(session, Projector, projector_id, "projector")
    return page_of(
        session, ProjectorCalibration, ProjectorCalibration.projector_id, projector_id, page
    )
