"""Schemas of zones (spec 09): polygons of a space's floor plan with inertia and loitering."""

from __future__ import annotations

from pydantic import BaseModel, Field

from server.schemas.common import ABSENT, Finite, Name, Schema
from server.schemas.registry import Polygon

# An inertia or loitering time above a day says nothing a home automation can use.
MAX_SECONDS = 86400.0


class ZoneCreate(Schema):
    name: Name = Field(description="Its slug (lower case, other characters as -) is its topic.")
    polygon: Polygon
    inertia_s: Finite = Field(
        1.0,
        ge=0,
        le=MAX_SECONDS,
        description="Time inside before a person counts as entered "
        "(and outside before they have left), s.",
    )
    loiter_s: Finite = Field(
        0.0, ge=0, le=MAX_SECONDS, description="Time inside that gives a loiter event, s; 0: none."
    )


class ZoneUpdate(Schema):
    name: Name = ABSENT
    polygon: Polygon = ABSENT
    inertia_s: Finite = Field(ABSENT, ge=0, le=MAX_SECONDS)
    loiter_s: Finite = Field(ABSENT, ge=0, le=MAX_SECONDS)


class ZoneRead(BaseModel):
    id: int | None = Field(description="The zone's id; null for a room (see room_id).")
    room_id: int | None = Field(description="The room's id when the zone is a room (read-only).")
    space_id: int
    name: str
    slug: str
    polygon: list[list[float]]
    inertia_s: float
    loiter_s: float
    read_only: bool
    occupancy: int | None = Field(description="People counted in the zone now.")
