"""Schemas of API tokens and of the dashboard's sign-in."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from server.schemas.common import Id, Name, ReadSchema, Schema, UtcDatetime

Scope = Literal["read", "write", "admin", "ingest"]


class TokenCreate(Schema):
    name: Name
    scopes: Annotated[list[Scope], Field(min_length=1, max_length=4)] = Field(
        description="read: GET everything; write: also create/change/delete (and ingest); "
        "admin: also tokens; ingest: a camera node's token, which may only post observations "
        "and heartbeats and read its cameras and their streams."
    )
    camera_ids: Annotated[list[Id], Field(min_length=1, max_length=1000)] | None = Field(
        None,
        description="With the ingest scope alone: the only cameras the token may speak for "
        "(omit: any camera).",
    )

    @model_validator(mode="after")
    def _cameras_bind_ingest_only(self) -> TokenCreate:
        if self.camera_ids is not None and set(self.scopes) != {"ingest"}:
            raise ValueError(
                "camera_ids binds an ingest token to its cameras: give it with scopes "
                '["ingest"] alone (read and write tokens reach every camera)'
            )
        return self


class TokenRead(ReadSchema):
    id: int
    name: str
    scopes: list[Scope]
    camera_ids: list[int] | None = None
    revoked: bool
    created_at: UtcDatetime


class TokenCreated(TokenRead):
    token: str = Field(description="The bearer token; shown only in this response.")


class SessionLogin(Schema):
    token: Annotated[str, Field(min_length=1, max_length=512)] = Field(
        description="A read, write or admin token (the admin token `intspace serve` printed)."
    )


class SessionState(ReadSchema):
    authenticated: bool
    via: Literal["cookie", "bearer"] | None = Field(
        None, description="cookie: a dashboard sign-in; bearer: an Authorization header."
    )
    name: str | None = None
    scopes: list[Scope] = Field(default_factory=list)
    camera_ids: list[int] | None = None
    expires_at: float | None = Field(None, description="When the sign-in ends (Unix s).")
    csrf_token: str | None = Field(
        None,
        description="Send it as X-CSRF-Token with every write through the dashboard session.",
    )
    public_reads: bool = False
