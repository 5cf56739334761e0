"""Spaces: the homes (or labs) that hold rooms and devices."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, status
from sqlalchemy import select

from server.api._crud import apply_changes, check_unique_name, get_or_404, paginate
from server.api.deps import PageDep, ReadAccess, SceneDep, SessionDep, WriteAccess
from server.api.errors import PROBLEM_RESPONSES
from server.db.models import Space
from server.schemas.common import MAX_ID, Page
from server.schemas.registry import SpaceCreate, SpaceRead, SpaceUpdate

router = APIRouter(prefix="/spaces", tags=["spaces"], responses=PROBLEM_RESPONSES)
SpaceId = Annotated[int, Path(ge=1, le=MAX_ID)]


@router.get("", response_model=Page[SpaceRead], dependencies=[ReadAccess])
def list_spaces(session: SessionDep, page: PageDep):
    """Return a page of spaces, oldest first."""
    return paginate(session, select(Space).order_by(Space.id), page)


@router.post(
    "", response_model=SpaceRead, status_code=status.HTTP_201_CREATED, dependencies=[WriteAccess]
)
def create_space(body: SpaceCreate, session: SessionDep):
    """Create a space; its name is its own (409 when another space has it)."""
    check_unique_name(session, None, Space, body.model_dump(), "space")
    space = Space(**body.model_dump())
    session.add(space)
    session.commit()
    return space


@router.get("/{space_id}", response_model=SpaceRead, dependencies=[ReadAccess])
def get_space(space_id: SpaceId, session: SessionDep):
    """Return one space."""
    return get_or_404(session, Space, space_id, "space")


@router.patch("/{space_id}", response_model=SpaceRead, dependencies=[WriteAccess])
def update_space(space_id: SpaceId, body: SpaceUpdate, session: SessionDep):
    """Change the fields given."""
    space = get_or_404(session, Space, space_id, "space")
    changes = body.model_dump(exclude_unset=True)
    check_unique_name(session, space, Space, changes, "space")
    apply_changes(space, changes)
    session.commit()
    return space


@router.delete("/{space_id}", status_code=status.HTTP_204_NO_CONTENT, dependencies=[WriteAccess])
def delete_space(space_id: SpaceId, session: SessionDep, scene: SceneDep) -> None:
    """Delete a space with its rooms; its devices stay, unassigned."""
    space = get_or_404(session, Space, space_id, "space")
    session.delete(space)
    session.commit()
    scene.rooms_changed(session)
