"""Arms on robots: kinematic model (DH parameters, joint limits, tool, mount), eye-in-hand
camera, hand-eye transform and its history, the arm's hand-eye calibration runs (made and
applied by server.services.calibration.hand_eye through /calibration-runs)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Path, Query, status
from sqlalchemy import select

from server.api._crud import apply_changes, check_references, get_or_404, page_of, paginate
from server.api.deps import PageDep, ReadAccess, SessionDep, WriteAccess
from server.api.errors import PROBLEM_RESPONSES, FieldProblem
from server.db.models import Arm, CalibrationRun, Camera, HandEyeCalibration, Robot
from server.schemas.calibration import CalibrationRunRead
from server.schemas.common import MAX_ID, Page
from server.schemas.manipulation import (
    ArmCreate,
    ArmRead,
    ArmUpdate,
    HandEyeCalibrationRead,
)
from server.services.manipulation import ArmKinematics, arm_model_problem, arm_read

router = APIRouter(prefix="/arms", tags=["arms"], responses=PROBLEM_RESPONSES)
ArmId = Annotated[int, Path(ge=1, le=MAX_ID)]


def _check_unique_name(session, arm: Arm | None, changes: dict[str, Any]) -> None:
    name = changes.get("name", getattr(arm, "name", None))
    robot_id = changes.get("robot_id", getattr(arm, "robot_id", None))
    stmt = select(Arm.id).where(Arm.name == name, Arm.robot_id == robot_id)
    if arm is not None:
        stmt = stmt.where(Arm.id != arm.id)
    clash = session.scalar(stmt.limit(1))
    if clash is not None:
        raise FieldProblem(409, "name", f"arm {clash} is already called {name!r} on this robot")


def _check_model(arm: Arm | None, changes: dict[str, Any]) -> None:
    keys = ("dh", "limits", "tool", "home", "T_robot_arm", "T_ee_camera")
    merged = {k: changes[k] if k in changes else getattr(arm, k, None) for k in keys}
    problem = arm_model_problem(ArmKinematics.from_json(merged))
    if problem is not None:
        raise FieldProblem(422, *problem)


def _references(changes: dict[str, Any]) -> dict:
    return {
        "robot_id": (Robot, changes.get("robot_id")),
        "camera_id": (Camera, changes.get("camera_id")),
    }


@router.get("", response_model=Page[ArmRead], dependencies=[ReadAccess])
def list_arms(
    session: SessionDep,
    page: PageDep,
    robot_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
):
    """Return a page of arms, optionally of one robot."""
    stmt = select(Arm).order_by(Arm.id)
    if robot_id is not None:
        stmt = stmt.where(Arm.robot_id == robot_id)
    listing = paginate(session, stmt, page)
    listing["items"] = [arm_read(arm) for arm in listing["items"]]
    return listing


@router.post(
    "", response_model=ArmRead, status_code=status.HTTP_201_CREATED, dependencies=[WriteAccess]
)
def create_arm(body: ArmCreate, session: SessionDep):
    """Attach an arm to a robot (names are unique on a robot: 409 on a clash). Kinematic
    fields left out are the twin's arm's."""
    data = body.model_dump()
    check_references(session, _references(data))
    _check_unique_name(session, None, data)
    _check_model(None, data)
    arm = Arm(**data)
    session.add(arm)
    session.commit()
    return arm_read(arm)


@router.get("/{arm_id}", response_model=ArmRead, dependencies=[ReadAccess])
def get_arm(arm_id: ArmId, session: SessionDep):
    """Return one arm."""
    return arm_read(get_or_404(session, Arm, arm_id, "arm"))


@router.patch("/{arm_id}", response_model=ArmRead, dependencies=[WriteAccess])
def update_arm(arm_id: ArmId, body: ArmUpdate, session: SessionDep):
    """Change the fields given (null clears an optional one). A T_ee_camera typed in replaces
    the applied hand-eye run's (the arm then has no hand-eye run)."""
    arm = get_or_404(session, Arm, arm_id, "arm")
    changes = body.model_dump(exclude_unset=True)
    for key in ("robot_id", "name", "dh", "limits", "tool", "home", "T_robot_arm"):
        if key in changes and changes[key] is None:
            raise FieldProblem(422, key, f"{key} cannot be cleared; give a value")
    check_references(session, _references(changes))
    _check_unique_name(session, arm, changes)
    _check_model(arm, changes)
    if "T_ee_camera" in changes:
        changes["hand_eye_run_id"] = None
    apply_changes(arm, changes)
    session.commit()
    return arm_read(arm)


@router.delete("/{arm_id}", status_code=status.HTTP_204_NO_CONTENT, dependencies=[WriteAccess])
def delete_arm(arm_id: ArmId, session: SessionDep) -> None:
    """Delete an arm and its hand-eye history (its runs and tasks stay, unassigned)."""
    session.delete(get_or_404(session, Arm, arm_id, "arm"))
    session.commit()


@router.get(
    "/{arm_id}/hand-eye-calibrations",
    response_model=Page[HandEyeCalibrationRead],
    dependencies=[ReadAccess],
)
def list_hand_eye_calibrations(arm_id: ArmId, session: SessionDep, page: PageDep):
    """Return the arm's hand-eye history (the runs applied to it), newest first."""
    get_or_404(session, Arm, arm_id, "arm")
    return page_of(session, HandEyeCalibration, HandEyeCalibration.arm_id, arm_id, page)


@router.get(
    "/{arm_id}/calibration-runs",
    response_model=Page[CalibrationRunRead],
    dependencies=[ReadAccess],
)
def list_arm_runs(arm_id: ArmId, session: SessionDep, page: PageDep):
    """Return the arm's hand-eye calibration runs, newest first."""
    get_or_404(session, Arm, arm_id, "arm")
    return page_of(session, CalibrationRun, CalibrationRun.arm_id, arm_id, page)
