"""Projectors: image size, intrinsics, distortion and pose of each projector."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Query, status
from sqlalchemy import select

from server.api._crud import (
    Unassigned,
    apply_changes,
    check_camera_model,
    check_references,
    check_unique_name,
    get_or_404,
    in_space,
    paginate,
)
from server.api.deps import PageDep, ReadAccess, SessionDep, WriteAccess
from server.api.errors import PROBLEM_RESPONSES
from server.db.models import Projector, Space
from server.schemas.common import MAX_ID, Page
from server.schemas.registry import ProjectorCreate, ProjectorRead, ProjectorUpdate

router = APIRouter(prefix="/projectors", tags=["projectors"], responses=PROBLEM_RESPONSES)
ProjectorId = Annotated[int, Path(ge=1, le=MAX_ID)]


@router.get("", response_model=Page[ProjectorRead], dependencies=[ReadAccess])
def list_projectors(
    session: SessionDep,
    page: PageDep,
    space_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
    unassigned: Unassigned = False,
):
    """Return a page of projectors, optionally of one space (and those of no space)."""
    stmt = select(Projector).order_by(Projector.id)
    stmt = in_space(stmt, Projector.space_id, space_id, unassigned)
    return paginate(session, stmt, page)


@router.post(
    "",
    response_model=ProjectorRead,
    status_code=status.HTTP_201_CREATED,
    dependencies=[WriteAccess],
)
def create_projector(body: ProjectorCreate, session: SessionDep):
    """Create a projector (pose as T_world_projector or position + quaternion_xyzw)."""
    check_references(session, {"space_id": (Space, body.space_id)})
    changes = body.changes()
    check_unique_name(session, None, Projector, changes, "projector")
    check_camera_model(None, changes)
    projector = Projector(**changes)
    session.add(projector)
    session.commit()
    return projector


@router.get("/{projector_id}", response_model=ProjectorRead, dependencies=[ReadAccess])
def get_projector(projector_id: ProjectorId, session: SessionDep):
    """Return one projector."""
    return get_or_404(session, Projector, projector_id, "projector")


@router.patch("/{projector_id}", response_model=ProjectorRead, dependencies=[WriteAccess])
def update_projector(projector_id: ProjectorId, body: ProjectorUpdate, session: SessionDep):
    """Change the fields given (null clears an optional one)."""
    projector = get_or_404(session, Projector, projector_id, "projector")
    changes = body.changes()
    check_references(session, {"space_id": (Space, changes.get("space_id"))})
    check_unique_name(session, projector, Projector, changes, "projector")
    check_camera_model(projector, changes)
    apply_changes(projector, changes)
    session.commit()
    return projector


@router.delete(
    "/{projector_id}", status_code=status.HTTP_204_NO_CONTENT, dependencies=[WriteAccess]
)
def delete_projector(projector_id: ProjectorId, session: SessionDep) -> None:
    """Delete a projector."""
    session.delete(get_or_404(session, Projector, projector_id, "projector"))
    session.commit()
