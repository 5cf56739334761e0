"""Schemas of the home integration's state."""

from __future__ import annotations

from pydantic import BaseModel, Field


class BrokerStatus(BaseModel):
    url: str = Field(description="The broker's URL, its password masked.")
    connected: bool
    since: float | None = Field(description="When it connected or was lost (Unix s).")
    dropped: int = Field(description="Messages dropped because the queue was full.")
    queued: int
    pending_retained: int
    published: int
    received: int
    connections: int
    last_error: str | None


class MqttStatus(BrokerStatus):
    prefix: str
    discovery_prefix: str
    available_owner: bool = Field(description="Whether this process publishes <prefix>/available.")
    events: int


class FrigateStatus(BaseModel):
    broker: BrokerStatus | None = None
    events: int
    fed: int
    refed: int
    late: int
    ignored: int
    unknown_camera: int
    expired: int
    dropped: int
    errors: int
    held: int = Field(description="Objects Frigate keeps now.")
    inbox: int


class HomeStatus(BaseModel):
    mqtt: MqttStatus | None
    frigate: FrigateStatus | None
