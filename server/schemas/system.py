"""Schemas of health and the scene link."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field


class Health(BaseModel):
    status: Literal["ok", "failing"]
    storage: str = Field("ok", description='"ok", or why the storage is failing')
    version: str
    database: str = Field(description="sqlite or postgresql")
    schema_revision: str | None
    public_reads: bool
    simulation: bool
    scene: bool = Field(description="Whether the viser scene runs in this process.")


class SceneLink(BaseModel):
    viser_url: str
