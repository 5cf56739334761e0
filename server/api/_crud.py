"""Helpers the resource routers share: fetch-or-404, reference checks, paginated listings."""

from __future__ import annotations

from typing import Annotated, Any, TypeVar

from fastapi import HTTPException, Query, status
from sqlalchemy import Select, func, or_, select
from sqlalchemy.orm import Session

from server.api.deps import Pagination
from server.api.errors import FieldProblem
from server.db.base import Base
from server.schemas.registry import camera_model_problem

M = TypeVar("M", bound=Base)
S = TypeVar("S", bound=Select[Any])

# A list route's `unassigned` filter: the devices registered in no space.
Unassigned = Annotated[
    bool,
    Query(
        description="With space_id: that space's rows and those of no space; alone: only "
        "those of no space."
    ),
]


def in_space(stmt: S, column: Any, space_id: int | None, unassigned: bool) -> S:
    """Return `stmt` keeping the rows whose `column` is `space_id` and, with `unassigned`,
    those of no space (only those when `space_id` is None); every row when neither is set."""
    if space_id is not None and unassigned:
        return stmt.where(or_(column == space_id, column.is_(None)))
    if space_id is not None:
        return stmt.where(column == space_id)
    if unassigned:
        return stmt.where(column.is_(None))
    return stmt


def get_or_404(session: Session, model: type[M], id: int, what: str) -> M:
    """Return the row `id` of `model`, raising 404 naming `what` when there is none."""
    row = session.get(model, id)
    if row is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"no {what} with id {id}")
    return row


def check_references(session: Session, references: dict[str, tuple[type[Base], Any]]) -> None:
    """Raise 422 naming the field when a referenced id (field -> (model, id)) does not exist;
    None ids are fine (no reference)."""
    for field, (model, id) in references.items():
        if id is not None and session.get(model, id) is None:
            table = model.__tablename__.rstrip("s")
            raise FieldProblem(422, field, f"no {table} with id {id}")


def check_unique_name(
    session: Session, row: Any, model: type[Base], changes: dict[str, Any], what: str
) -> None:
    """Raise 409 naming the clash when `model`'s row as it will be after `changes` (to `row`,
    or to nothing when it is created) has the name of another row of its space (spaces: of
    another space). Names are how users and camera nodes tell things apart."""
    name = changes.get("name", getattr(row, "name", None))
    if name is None:
        return
    stmt = select(model.id).where(model.name == name)  # type: ignore[attr-defined]
    scoped = hasattr(model, "space_id")
    if scoped:
        space_id = changes["space_id"] if "space_id" in changes else getattr(row, "space_id", None)
        column = model.space_id  # type: ignore[attr-defined]
        stmt = stmt.where(column.is_(None) if space_id is None else column == space_id)
    if row is not None:
        stmt = stmt.where(model.id != row.id)  # type: ignore[attr-defined]
    clash = session.scalar(stmt.limit(1))
    if clash is not None:
        where = " in this space" if scoped else ""
        raise FieldProblem(409, "name", f"{what} {clash} is already called {name!r}{where}")


def paginate(session: Session, stmt: Select[Any], page: Pagination) -> dict[str, Any]:
    """Return {items, total, limit, offset} for `stmt` (ordered by the caller)."""
    total = session.scalar(select(func.count()).select_from(stmt.order_by(None).subquery()))
    items = session.scalars(stmt.limit(page.limit).offset(page.offset)).all()
    return {"items": items, "total": total or 0, "limit": page.limit, "offset": page.offset}


def page_of(
    session: Session, model: type[Base], column: Any, owner_id: int, page: Pagination
) -> dict[str, Any]:
    """Return a page of `model`'s rows whose `column` is `owner_id` (a camera's calibrations,
    an arm's runs), newest first."""
    stmt = select(model).where(column == owner_id).order_by(model.id.desc())  # type: ignore[attr-defined]
    return paginate(session, stmt, page)


def apply_changes(row: Base, changes: dict[str, Any]) -> None:
    """Set the given attributes on `row`."""
    for key, value in changes.items():
        setattr(row, key, value)


def check_camera_model(row: Any, changes: dict[str, Any]) -> None:
    """Raise 422 naming the field when a camera's or projector's model (K, dist, image size) as
    it will be after `changes` (to `row`, or to nothing when it is created) is implausible or
    one core cannot use."""
    keys = ("K", "dist", "width", "height")
    # A row's and a create body's width and height are never None (both required).
    merged: dict[str, Any] = {
        key: changes[key] if key in changes else getattr(row, key, None) for key in keys
    }
    problem = camera_model_problem(merged["K"], merged["dist"], merged["width"], merged["height"])
    if problem is not None:
        raise FieldProblem(422, problem[0], problem[1])
