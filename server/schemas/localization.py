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
# A batch is one camera node's frames of a moment (the ingest bench sends 2,000): 20,000 keeps
# the memory of validating the largest under 50 MB.
MAX_OBSERVATIONS = 20_000


Kind = Literal["robot", "person", "unknown"]


class Observation(Schema):
    """One detection: the camera, its capture time (Unix seconds on the service's clock), the
    distorted pixel and its uncertainty (sigma_px, or a 2x2 covariance px^2; 1 px when
    neither), its kind where the sender knows it, the height (m) of the point it measures, and
    the target's label only when the sender knows which target it is."""

    camera_id: Id
    t: Finite
    pixel: Pixel
    sigma_px: Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)] | None = None
    cov: Cov2 | None = None
    kind: Kind | None = None
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


class EmptyFrame(Schema):
    """A camera frame in which the sender detected nothing: the camera and its capture time
    (Unix seconds on the service's clock). It tells the space's tracker that the camera looked
    at that time, so the tracker need not wait for that camera's frames up to it."""

    camera_id: Id
    t: Finite


class ObservationBatch(Schema):
    observations: Annotated[list[Observation], Field(max_length=MAX_OBSERVATIONS)] = Field(
        default_factory=list
    )
    empty_frames: Annotated[
        list[EmptyFrame],
        Field(
            max_length=MAX_OBSERVATIONS,
            description="Camera frames (camera_id, t) processed with no detection.",
        ),
    ] = Field(default_factory=list)

    @model_validator(mode="after")
    def _something(self) -> ObservationBatch:
        if not self.observations and not self.empty_frames:
            raise ValueError("a batch needs observations, empty_frames or both; it has neither")
        return self


class Position(ReadSchema):
    target: str | None
    t: float
    xy: list[float] | None = Field(description="Floor (x, y), metres; null if not located.")
    cov: list[list[float]] | None = Field(description="2x2 covariance, m^2.")
    n_cameras: int
    estimator: Literal["ml"] = "ml"
    status: Literal["ok", "too_few_cameras", "degenerate", "behind_camera"] = "ok"


class PositionBatch(ReadSchema):
    stored: int = Field(description="Detections committed to the database.")
    frames: int = Field(
        description="Camera frames (camera, time) queued for the tracker, empty ones included."
    )
    late: int = Field(
        description="Frames older than what the space's tracker already processed: stored, "
        "not tracked."
    )
    ignored: int = Field(
        0,
        description="Robot detections of cameras whose space has no registered robot: neither "
        "stored nor tracked (a red thing taken for a marker where no robot can be).",
    )
    positions: list[Position] = Field(
        description="The labelled (target, t) groups located at once by ML on the plane."
    )


TargetState = Literal["confirmed", "coasting", "ended"]


class TargetRead(ReadSchema):
    id: int
    label: str
    kind: str
    state: TargetState
    first_seen: float | None = Field(description="First update, Unix seconds.")
    last_seen: float | None = Field(description="Latest update, Unix seconds.")
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


class RecentTrack(ReadSchema):
    target_id: int
    label: str
    kind: str
    state: TargetState
    points: list[list[float]] = Field(description="[t, x, y] rows, oldest first.")


class TrackSet(ReadSchema):
    since: float
    tracks: list[RecentTrack]
