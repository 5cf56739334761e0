"""The home integration's state (spec 09): the MQTT broker's connection and Frigate's."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from server.api.deps import FrigateDep, HomeDep, ReadAccess
from server.api.errors import PROBLEM_RESPONSES
from server.schemas.home import HomeStatus

router = APIRouter(prefix="/home", tags=["home"], responses=PROBLEM_RESPONSES)


@router.get("/status", response_model=HomeStatus, dependencies=[ReadAccess])
def home_status(publisher: HomeDep, frigate: FrigateDep) -> dict[str, Any]:
    """Return the MQTT publisher's connection (URL without its password, connected or not and
    since when, messages dropped and queued) and Frigate's, each null when not configured."""
    mqtt = None
    if publisher is not None:
        mqtt = {
            **publisher.link.status(),
            "prefix": publisher.prefix,
            "discovery_prefix": publisher.discovery_prefix,
            "available_owner": publisher.available_owner,
            "events": publisher.events,
        }
    return {"mqtt": mqtt, "frigate": None if frigate is None else frigate.status()}
