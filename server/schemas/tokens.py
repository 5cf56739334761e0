"""Schemas of API tokens."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from server.schemas.common import Name, ReadSchema, Schema, UtcDatetime

Scope = Literal["read", "write", "admin"]


class TokenCreate(Schema):
    name: Name
    scopes: Annotated[list[Scope], Field(min_length=1, max_length=3)] = Field(
        description="read: GET everything; write: also create/change/delete; admin: also tokens."
    )


class TokenRead(ReadSchema):
    id: int
    name: str
    scopes: list[Scope]
    revoked: bool
    created_at: UtcDatetime


class TokenCreated(TokenRead):
    token: str = Field(description="The bearer token; shown only in this response.")
