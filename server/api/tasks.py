"""Robot tasks on the digital twin: a fetch (grasp episodes with an arm) or a survey runs in a
background thread of the task runner started with the service; its phase, progress and result
are stored as it goes and read back by id."""

from __future__ import annotations

import secrets
from typing import Annotated

from fastapi import APIRouter, Body, Depends, HTTPException, Path, Query, status
from sqlalchemy import select

from server.api._crud import check_references, get_or_404, paginate
from server.api.deps import (
    PageDep,
    ReadAccess,
    SessionDep,
    TaskRunnerDep,
    TwinDep,
    WriteAccess,
)
from server.api.errors import PROBLEM_RESPONSES, FieldProblem
from server.db.models import Arm, Task
from server.schemas.common import MAX_ID, Page
from server.schemas.manipulation import FetchTaskCreate, TaskStatus
from server.services.manipulation import (
    ArmKinematics,
    FetchRefused,
    closed_form,
    fetch_target,
)
from server.services.survey import AnyTaskRead, SurveyTaskCreate, survey_task

router = APIRouter(prefix="/tasks", tags=["tasks"], responses=PROBLEM_RESPONSES)
TaskId = Annotated[int, Path(ge=1, le=MAX_ID)]


def settle_stale_tasks(session: SessionDep, runner: TaskRunnerDep) -> None:
    """Mark interrupted the tasks of processes that stopped, so that a read never shows a task
    running that nothing runs (the runner's heartbeat does it too, every few seconds)."""
    runner.settle(session)


Settled = Depends(settle_stale_tasks)
TaskCreate = Annotated[FetchTaskCreate | SurveyTaskCreate, Body(discriminator="kind")]


@router.post(
    "", response_model=AnyTaskRead, status_code=status.HTTP_202_ACCEPTED, dependencies=[WriteAccess]
)
def create_task(body: TaskCreate, session: SessionDep, twin: TwinDep, runner: TaskRunnerDep):
    """Start a task on the twin; poll GET /tasks/{id} for its phase, progress and result.
    Kind "fetch": the arm fetches a marked box from the dining table, `episodes` times; with
    `object` (an id or name of the twin's semantic map), the box at the pose the map holds:
    404 when the map has no such object, 409 when two have that name or the arm cannot fetch
    it from there.
    Kind "survey": the robot tours the home, reads the landmarks and fills the twin space's
    semantic and navigation maps (GET /maps/semantic) as it reads them."""
    if twin is None or twin.space_id is None:
        raise HTTPException(
            status.HTTP_409_CONFLICT,
            detail=f"a {body.kind} runs on the digital twin; start the service with "
            "INTSPACE_SIMULATION=true",
        )
    if isinstance(body, SurveyTaskCreate):
        task = survey_task(session, body, runner.lease())
        runner.submit(task.id)
        return task
    check_references(session, {"arm_id": (Arm, body.arm_id)})
    arm = session.get(Arm, body.arm_id)
    assert arm is not None
    values = ArmKinematics.of(arm)
    if not closed_form(values):
        raise FieldProblem(
            422,
            "arm_id",
            f"arm {arm.id} is not of the Puma type whose closed-form inverse kinematics places "
            "the twin's robot base for the grasp",
        )
    inputs = body.model_dump()
    if inputs["seed"] is None:
        inputs["seed"] = secrets.randbelow(2**31)
    inputs["arm"] = values.as_json()
    if body.object is not None:
        try:
            target = fetch_target(session, twin.space_id, body.object, values)
            inputs["object"] = target.as_json()
        except FetchRefused as exc:
            raise FieldProblem(exc.status, exc.field, str(exc)) from exc
    task = Task(
        kind=body.kind,
        status="queued",
        arm_id=arm.id,
        inputs=inputs,
        phase="queued",
        progress=0.0,
        **runner.lease(),
    )
    session.add(task)
    session.commit()
    runner.submit(task.id)
    return task


@router.get("", response_model=Page[AnyTaskRead], dependencies=[ReadAccess, Settled])
def list_tasks(
    session: SessionDep,
    page: PageDep,
    arm_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
    status: Annotated[TaskStatus | None, Query()] = None,
):
    """Return a page of tasks, newest first, optionally of one arm or one status."""
    stmt = select(Task).order_by(Task.id.desc())
    if arm_id is not None:
        stmt = stmt.where(Task.arm_id == arm_id)
    if status is not None:
        stmt = stmt.where(Task.status == status)
    return paginate(session, stmt, page)


@router.get("/{task_id}", response_model=AnyTaskRead, dependencies=[ReadAccess, Settled])
def get_task(task_id: TaskId, session: SessionDep):
    """Return a task: its status, phase, progress, and its result (episode by episode)."""
    return get_or_404(session, Task, task_id, "task")
