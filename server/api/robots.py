"""Robots: the mobile manipulator's kinematics, cameras and hand-eye transform."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Query, status
from sqlalchemy import select

from server.api._crud import (
    Unassigned,
    apply_changes,
    check_references,
    check_unique_name,
    get_or_404,
    in_space,
    paginate,
)
from server.api.deps import PageDep, ReadAccess, SessionDep, WriteAccess
from server.api.errors import PROBLEM_RESPONSES
from server.db.models import Camera, Robot, Space
from server.schemas.common import MAX_ID, Page
from server.schemas.registry import RobotCreate, RobotRead, RobotUpdate

router = APIRouter(prefix="/robots", tags=["robots"], responses=PROBLEM_RESPONSES)
RobotId = Annotated[int, Path(ge=1, le=MAX_ID)]


def _references(changes: dict) -> dict:
    return {
        "space_id": (Space, changes.get("space_id")),
        "onboard_camera_id": (Camera, changes.get("onboard_camera_id")),
        "hand_camera_id": (Camera, changes.get("hand_camera_id")),
    }


@router.get("", response_model=Page[RobotRead], dependencies=[ReadAccess])
def list_robots(
    session: SessionDep,
    page: PageDep,
    space_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
    unassigned: Unassigned = False,
):
    """Return a page of robots, optionally of one space (and those of no space)."""
    stmt = select(Robot).order_by(Robot.id)
    stmt = in_space(stmt, Robot.space_id, space_id, unassigned)
    return paginate(session, stmt, page)


@router.post(
    "", response_model=RobotRead, status_code=status.HTTP_201_CREATED, dependencies=[WriteAccess]
)
def create_robot(body: RobotCreate, session: SessionDep):
    """Create a robot."""
    data = body.model_dump()
    check_references(session, _references(data))
    check_unique_name(session, None, Robot, data, "robot")
    robot = Robot(**data)
    session.add(robot)
    session.commit()
    return robot


@router.get("/{robot_id}", response_model=RobotRead, dependencies=[ReadAccess])
def get_robot(robot_id: RobotId, session: SessionDep):
    """Return one robot."""
    return get_or_404(session, Robot, robot_id, "robot")


@router.patch("/{robot_id}", response_model=RobotRead, dependencies=[WriteAccess])
def update_robot(robot_id: RobotId, body: RobotUpdate, session: SessionDep):
    """Change the fields given (null clears an optional one)."""
    robot = get_or_404(session, Robot, robot_id, "robot")
    changes = body.model_dump(exclude_unset=True)
    check_references(session, _references(changes))
    check_unique_name(session, robot, Robot, changes, "robot")
    apply_changes(robot, changes)
    session.commit()
    return robot


@router.delete("/{robot_id}", status_code=status.HTTP_204_NO_CONTENT, dependencies=[WriteAccess])
def delete_robot(robot_id: RobotId, session: SessionDep) -> None:
    """Delete a robot (its cameras stay)."""
    session.delete(get_or_404(session, Robot, robot_id, "robot"))
    session.commit()
