"""Shared field types (finite numbers, matrices, names, ids), pagination and problem details."""

from __future__ import annotations

import types
import typing
from datetime import UTC, datetime
from typing import Annotated, Any, Generic, TypeVar, get_args, get_origin

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    Strict,
    StringConstraints,
)

T = TypeVar("T")

_UNIONS = (typing.Union, types.UnionType)

# PostgreSQL integers are 32-bit: larger ids can only be "not found", never an overflow error.
MAX_ID = 2**31 - 1


def _no_nul(value: str) -> str:
    # PostgreSQL text cannot hold NUL; refuse it for every backend alike.
    if "\x00" in value:
        raise ValueError("must not contain NUL characters")
    return value


def _utc(value: datetime) -> datetime:
    # SQLite hands timestamps back naive; they were written in UTC.
    return value if value.tzinfo is not None else value.replace(tzinfo=UTC)


Id = Annotated[int, Field(ge=1, le=MAX_ID)]
Name = Annotated[
    str,
    StringConstraints(strip_whitespace=True, min_length=1, max_length=200),
    AfterValidator(_no_nul),
]
Text = Annotated[str, StringConstraints(max_length=10_000), AfterValidator(_no_nul)]
Finite = Annotated[float, Field(allow_inf_nan=False)]
PixelCount = Annotated[int, Field(ge=1, le=100_000, description="pixels")]
UtcDatetime = Annotated[datetime, AfterValidator(_utc)]

Vec2 = Annotated[list[Finite], Field(min_length=2, max_length=2)]
Vec3 = Annotated[list[Finite], Field(min_length=3, max_length=3)]
Vec4 = Annotated[list[Finite], Field(min_length=4, max_length=4)]
Row3 = Annotated[list[Finite], Field(min_length=3, max_length=3)]
Row4 = Annotated[list[Finite], Field(min_length=4, max_length=4)]


def _intrinsic_matrix(K: list[list[float]]) -> list[list[float]]:
    if K[1][0] != 0 or K[2] != [0, 0, 1]:
        raise ValueError("K must be [[fx, s, u0], [0, fy, v0], [0, 0, 1]]")
    if K[0][0] <= 0 or K[1][1] <= 0:
        raise ValueError("K's focal lengths fx = K[0][0] and fy = K[1][1] must be positive")
    return K


def _rigid_transform(T: list[list[float]]) -> list[list[float]]:
    M = np.asarray(T, dtype=float)
    if not np.array_equal(M[3], [0.0, 0.0, 0.0, 1.0]):
        raise ValueError("the last row of a 4x4 rigid transform must be [0, 0, 0, 1]")
    R = M[:3, :3]
    # 1e-6 admits rotations printed with 7 significant digits.
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) <= 0:
        raise ValueError("the upper-left 3x3 block must be a rotation (orthonormal, det +1)")
    return T


Matrix3 = Annotated[
    list[Row3],
    Field(min_length=3, max_length=3, description="3x3 intrinsic matrix, row-major"),
    AfterValidator(_intrinsic_matrix),
]
RigidTransform = Annotated[
    list[Row4],
    Field(min_length=4, max_length=4, description="4x4 rigid transform, row-major, metres"),
    AfterValidator(_rigid_transform),
]


def _distortion(dist: list[float]) -> list[float]:
    if len(dist) not in (4, 5, 8, 12, 14):
        raise ValueError("OpenCV distortion has 4, 5, 8, 12 or 14 coefficients")
    return dist


Distortion = Annotated[
    list[Finite],
    Field(
        min_length=4,
        max_length=14,
        description="OpenCV distortion coefficients (k1, k2, p1, p2[, k3, ...]): 4, 5, 8, 12 "
        "or 14 values",
    ),
    AfterValidator(_distortion),
]


# An update schema's default for an absent field: the field keeps its type (not optional), so an
# explicit null is refused where the column is required. Typed Any so that such a field may
# default to it.
ABSENT: Any = None


class Schema(BaseModel):
    """Base of request schemas: unknown fields are errors, not silently dropped, and a boolean
    field takes only true or false (pydantic's lax mode would read 1, "yes" or "on" too)."""

    model_config = ConfigDict(extra="forbid")

    @classmethod
    def __pydantic_init_subclass__(cls, **kwargs: Any) -> None:
        super().__pydantic_init_subclass__(**kwargs)
        # Strict on the boolean fields only, decided once per class: no cost per request.
        changed = False
        for field in cls.model_fields.values():
            annotation = field.annotation
            union = get_origin(annotation) in _UNIONS
            if (annotation is bool or (union and bool in get_args(annotation))) and not any(
                isinstance(m, Strict) for m in field.metadata
            ):
                field.metadata.append(Strict())
                changed = True
        if changed:
            cls.model_rebuild(force=True)


class ReadSchema(BaseModel):
    """Base of response schemas, read from ORM objects."""

    model_config = ConfigDict(from_attributes=True)


def stored_json(result: BaseModel) -> dict[str, Any]:
    """Return a result as its JSON column stores it (a run's or a task's): the fields that were
    set, none filled in by defaults (a result so far lacks the final figures)."""
    return result.model_dump(exclude_unset=True)


class Page(BaseModel, Generic[T]):
    """One page of a listing: the items, the total count and the window asked for."""

    items: list[T]
    total: int = Field(description="Number of items matching the filters, over all pages.")
    limit: int
    offset: int


class FieldError(BaseModel):
    """What was wrong with one field of the request."""

    field: str = Field(description="Dotted path of the field, e.g. 'width' or 'K.2.0'.")
    location: str = Field(description="body, query, path, header or form.")
    reason: str


class Problem(BaseModel):
    """An error response (RFC 9457 problem details) with the offending fields."""

    type: str = "about:blank"
    title: str
    status: int
    detail: str
    errors: list[FieldError] = Field(
        default_factory=list, description="The first 20 field errors (error_count has them all)."
    )
    error_count: int = Field(0, description="How many field errors the request had in all.")
    request_id: str | None = Field(
        None, description="On a 500: the id the server log files its traceback under."
    )
