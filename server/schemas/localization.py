"""Schemas of localisation: batched detections in, floor positions out; targets and tracks."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from server.schemas.common import Finite, Id, ReadSchema, Schema, UtcDatetime

Pixel = Annotated[list[Finite], Field(min_length=2, max_length=2)]
Cov2 = Annotated[
    list[Annotated[list[Finite], Field(min_length=2, max_length=2)]],
    Field(min_length=2, max_length=2),
]
MAX_OBSERVATIONS = 100_000


class Observation(Schema):
    """One detection: the camera, its time (s, the sender's clock), the distorted pixel and its
    uncertainty (sigma_px, or a 2x2 covariance px^2), the target's label and height (m)."""

    camera_id: Id
    t: Finite
    pixel: Pixel
    sigma_px: Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)] | None = None
    cov: Cov2 | None = None
    target: Annotated[str, Field(min_length=1, max_length=200)] | None = None
    height: Annotated[float, Field(ge=-10, le=10, allow_inf_nan=False)] = 0.0

    @model_validator(mode="after")
    def _one_uncertainty(self) -> Observation:
        if self.sigma_px is not None and self.cov is not None:
            raise ValueError("give sigma_px or cov, not both")
        if self.cov is not None:
            (a, b), (c, d) = self.cov
            if abs(b - c) > 1e-9 * max(abs(a), abs(d), 1.0) or a <= 0 or a * d - b * c <= 0:
                raise ValueError("cov must be symmetric positive definite")
        return self


class ObservationBatch(Schema):
    observations: Annotated[list[Observation], Field(min_length=1, max_length=MAX_OBSERVATIONS)]


class Position(ReadSchema):
    target: str | None
    t: float
    xy: list[float] | None = Field(description="Floor (x, y), metres; null if not located.")
    cov: list[list[float]] | None = Field(description="2x2 covariance, m^2.")
    n_cameras: int
    estimator: Literal["ml"] = "ml"
    status: Literal["ok", "too_few_cameras", "degenerate", "behind_camera"] = "ok"


class PositionBatch(ReadSchema):
    positions: list[Position]


class TargetRead(ReadSchema):
    id: int
    label: str
    kind: str
    space_id: int | None
    t: float | None
    xy: list[float] | None
    cov: list[list[float]] | None
    created_at: UtcDatetime
    updated_at: UtcDatetime


class TrackPointRead(ReadSchema):
    t: float
    xy: list[float]
    cov: list[list[float]]


class Track(ReadSchema):
    target_id: int
    points: list[TrackPointRead]
