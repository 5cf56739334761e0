"""Landmarks: printed markers with their payload, physical size and world pose when known."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Query, status
from sqlalchemy import select

from server.api._crud import apply_changes, check_references, get_or_404, paginate
from server.api.deps import PageDep, ReadAccess, SessionDep, WriteAccess
from server.api.errors import PROBLEM_RESPONSES
from server.db.models import Landmark, Space
from server.schemas.common import MAX_ID, Page
from server.schemas.registry import LandmarkCreate, LandmarkKind, LandmarkRead, LandmarkUpdate

router = APIRouter(prefix="/landmarks", tags=["landmarks"], responses=PROBLEM_RESPONSES)
LandmarkId = Annotated[int, Path(ge=1, le=MAX_ID)]


@router.get("", response_model=Page[LandmarkRead], dependencies=[ReadAccess])
def list_landmarks(
    session: SessionDep,
    page: PageDep,
    space_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
    kind: Annotated[LandmarkKind | None, Query()] = None,
):
    """Return a page of landmarks, optionally of one space or one kind."""
    stmt = select(Landmark).order_by(Landmark.id)
    if space_id is not None:
        stmt = stmt.where(Landmark.space_id == space_id)
    if kind is not None:
        stmt = stmt.where(Landmark.kind == kind)
    return paginate(session, stmt, page)


@router.post(
    "",
    response_model=LandmarkRead,
    status_code=status.HTTP_201_CREATED,
    dependencies=[WriteAccess],
)
def create_landmark(body: LandmarkCreate, session: SessionDep):
    """Create a landmark."""
    check_references(session, {"space_id": (Space, body.space_id)})
    landmark = Landmark(**body.model_dump())
    session.add(landmark)
    session.commit()
    return landmark


@router.get("/{landmark_id}", response_model=LandmarkRead, dependencies=[ReadAccess])
def get_landmark(landmark_id: LandmarkId, session: SessionDep):
    """Return one landmark."""
    return get_or_404(session, Landmark, landmark_id, "landmark")


@router.patch("/{landmark_id}", response_model=LandmarkRead, dependencies=[WriteAccess])
def update_landmark(landmark_id: LandmarkId, body: LandmarkUpdate, session: SessionDep):
    """Change the fields given (null clears an optional one)."""
    landmark = get_or_404(session, Landmark, landmark_id, "landmark")
    changes = body.model_dump(exclude_unset=True)
    check_references(session, {"space_id": (Space, changes.get("space_id"))})
    apply_changes(landmark, changes)
    session.commit()
    return landmark


@router.delete("/{landmark_id}", status_code=status.HTTP_204_NO_CONTENT, dependencies=[WriteAccess])
def delete_landmark(landmark_id: LandmarkId, session: SessionDep) -> None:
    """Delete a landmark."""
    session.delete(get_or_404(session, Landmark, landmark_id, "landmark"))
    session.commit()
