"""Zones: polygons of a space's floor plan whose occupancy and events the service follows
(spec 09). A space's rooms are listed as zones too, read-only."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, status
from sqlalchemy import select
from sqlalchemy.orm import Session

from server.api._crud import apply_changes, get_or_404
from server.api.deps import ReadAccess, SessionDep, WriteAccess, ZonesDep
from server.api.errors import PROBLEM_RESPONSES, FieldProblem
from server.db.models import Room, Space, Zone
from server.schemas.common import MAX_ID
from server.schemas.zones import ZoneCreate, ZoneRead, ZoneUpdate
from server.services.zones import ZoneService, load_zone_defs, slugify, zone_read

router = APIRouter(tags=["zones"], responses=PROBLEM_RESPONSES)
SpaceId = Annotated[int, Path(ge=1, le=MAX_ID)]
ZoneId = Annotated[int, Path(ge=1, le=MAX_ID)]


def _slug_of(session: Session, space_id: int, name: str, zone_id: int | None) -> str:
    """Return the slug of `name`, raising 422 when it has none and 409 when a zone or room of
    the space has it already (the slug is the zone's MQTT topic)."""
    slug = slugify(name)
    if not slug:
        raise FieldProblem(422, "name", "must contain a letter or a digit (its slug is a topic)")
    stmt = select(Zone.id).where(Zone.space_id == space_id, Zone.slug == slug)
    if zone_id is not None:
        stmt = stmt.where(Zone.id != zone_id)
    if session.scalar(stmt.limit(1)) is not None:
        raise FieldProblem(409, "name", f"a zone of space {space_id} has the slug {slug!r}")
    rooms = session.scalars(select(Room.name).where(Room.space_id == space_id))
    if any(slugify(r) == slug for r in rooms):
        raise FieldProblem(409, "name", f"a room of space {space_id} has the slug {slug!r}")
    return slug


def _read(session: Session, zones: ZoneService | None, zone: Zone) -> ZoneRead:
    defs = [d for d in load_zone_defs(session, zone.space_id) if d.key == ("zone", zone.id)]
    occ = zones.occupancy(zone.space_id) if zones is not None else None
    return zone_read(defs[0], occ)


@router.get("/spaces/{space_id}/zones", response_model=list[ZoneRead], dependencies=[ReadAccess])
def list_zones(space_id: SpaceId, session: SessionDep, zones: ZonesDep):
    """Return the zones of a space, its rooms first (read-only), each with its occupancy."""
    get_or_404(session, Space, space_id, "space")
    occ = zones.occupancy(space_id) if zones is not None else None
    return [zone_read(d, occ) for d in load_zone_defs(session, space_id)]


@router.post(
    "/spaces/{space_id}/zones",
    response_model=ZoneRead,
    status_code=status.HTTP_201_CREATED,
    dependencies=[WriteAccess],
)
def create_zone(space_id: SpaceId, body: ZoneCreate, session: SessionDep, zones: ZonesDep):
    """Create a zone; its name's slug must be free in the space (409)."""
    get_or_404(session, Space, space_id, "space")
    slug = _slug_of(session, space_id, body.name, None)
    zone = Zone(space_id=space_id, slug=slug, **body.model_dump())
    session.add(zone)
    session.commit()
    if zones is not None:
        zones.changed()
    return _read(session, zones, zone)


@router.get("/zones/{zone_id}", response_model=ZoneRead, dependencies=[ReadAccess])
def get_zone(zone_id: ZoneId, session: SessionDep, zones: ZonesDep):
    """Return one zone with its occupancy."""
    return _read(session, zones, get_or_404(session, Zone, zone_id, "zone"))


@router.patch("/zones/{zone_id}", response_model=ZoneRead, dependencies=[WriteAccess])
def update_zone(zone_id: ZoneId, body: ZoneUpdate, session: SessionDep, zones: ZonesDep):
    """Change the fields given; a new name moves the zone's topics (the old ones are
    cleared)."""
    zone = get_or_404(session, Zone, zone_id, "zone")
    changes = body.model_dump(exclude_unset=True)
    if "name" in changes:
        changes["slug"] = _slug_of(session, zone.space_id, changes["name"], zone.id)
    apply_changes(zone, changes)
    session.commit()
    if zones is not None:
        zones.changed()
    return _read(session, zones, zone)


@router.delete(
    "/zones/{zone_id}", status_code=status.HTTP_204_NO_CONTENT, dependencies=[WriteAccess]
)
def delete_zone(zone_id: ZoneId, session: SessionDep, zones: ZonesDep) -> None:
    """Delete a zone (its topics and Home Assistant entities are cleared)."""
    session.delete(get_or_404(session, Zone, zone_id, "zone"))
    session.commit()
    if zones is not None:
        zones.changed()
