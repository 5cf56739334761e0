"""Rooms: floor polygons of a space, drawn as the scene's floor plan."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Query, status
from sqlalchemy import select

from server.api._crud import (
    apply_changes,
    check_references,
    check_unique_name,
    get_or_404,
    paginate,
)
from server.api.deps import PageDep, ReadAccess, SceneDep, SessionDep, WriteAccess
from server.api.errors import PROBLEM_RESPONSES
from server.db.models import Room, Space
from server.schemas.common import MAX_ID, Page
from server.schemas.registry import RoomCreate, RoomRead, RoomUpdate

router = APIRouter(prefix="/rooms", tags=["rooms"], responses=PROBLEM_RESPONSES)
RoomId = Annotated[int, Path(ge=1, le=MAX_ID)]


@router.get("", response_model=Page[RoomRead], dependencies=[ReadAccess])
def list_rooms(
    session: SessionDep,
    page: PageDep,
    space_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
):
    """Return a page of rooms, optionally of one space."""
    stmt = select(Room).order_by(Room.id)
    if space_id is not None:
        stmt = stmt.where(Room.space_id == space_id)
    return paginate(session, stmt, page)


@router.post(
    "", response_model=RoomRead, status_code=status.HTTP_201_CREATED, dependencies=[WriteAccess]
)
def create_room(body: RoomCreate, session: SessionDep, scene: SceneDep):
    """Create a room."""
    check_references(session, {"space_id": (Space, body.space_id)})
    check_unique_name(session, None, Room, body.model_dump(), "room")
    room = Room(**body.model_dump())
    session.add(room)
    session.commit()
    scene.rooms_changed(session)
    return room


@router.get("/{room_id}", response_model=RoomRead, dependencies=[ReadAccess])
def get_room(room_id: RoomId, session: SessionDep):
    """Return one room."""
    return get_or_404(session, Room, room_id, "room")


@router.patch("/{room_id}", response_model=RoomRead, dependencies=[WriteAccess])
def update_room(room_id: RoomId, body: RoomUpdate, session: SessionDep, scene: SceneDep):
    """Change the fields given."""
    room = get_or_404(session, Room, room_id, "room")
    changes = body.model_dump(exclude_unset=True)
    check_references(session, {"space_id": (Space, changes.get("space_id"))})
    check_unique_name(session, room, Room, changes, "room")
    apply_changes(room, changes)
    session.commit()
    scene.rooms_changed(session)
    return room


@router.delete("/{room_id}", status_code=status.HTTP_204_NO_CONTENT, dependencies=[WriteAccess])
def delete_room(room_id: RoomId, session: SessionDep, scene: SceneDep) -> None:
    """Delete a room."""
    session.delete(get_or_404(session, Room, room_id, "room"))
    session.commit()
    scene.rooms_changed(session)
