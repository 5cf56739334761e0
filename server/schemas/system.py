"""Schemas of health and the scene link."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from server.schemas.common import MAX_ID


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
    space_id: int | None = Field(
        None,
        description="The space the 3D scene shows (null when no space exists or the scene "
        "does not run in this process).",
    )


class SceneSpace(BaseModel):
    """Which space the 3D scene shows."""

    model_config = ConfigDict(extra="forbid")

    space_id: int = Field(ge=1, le=MAX_ID)
