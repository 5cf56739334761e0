"""The home integration's state (spec 09): the MQTT broker's connection and Frigate's."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request

from server.api.deps import ReadAccess
from server.api.errors import PROBLEM_RESPONSES
from server.schemas.home import HomeStatus

router = APIRouter(prefix="/home", tags=["home"], responses=PROBLEM_RESPONSES)


@router.get("/status", response_model=HomeStatus, dependencies=[ReadAccess])
def home_status(request: Request) -> dict[str, Any]:
    """Return the MQTT publisher's connection (URL without its password, connected or not and
    since when, messages dropped and queued) and Frigate's, each null when not configured."""
    publisher = getattr(request.app.state, "home", None)
    frigate = getattr(request.app.state, "frigate", None)
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
