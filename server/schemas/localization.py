"""Schemas of localisation: batched detections in, floor positions out; targets and tracks."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from core.localization.appearance import APPEARANCE_SIZE
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
# A box coordinate beyond this (pixels) is not of any camera's image.
MAX_BOX_COORDINATE = 100_000.0
BoxCoordinate = Annotated[
    float, Field(ge=-MAX_BOX_COORDINATE, le=MAX_BOX_COORDINATE, allow_inf_nan=False)
]
Box = Annotated[list[BoxCoordinate], Field(min_length=4, max_length=4)]
BoxSide = Literal["bottom", "top", "left", "right"]
Appearance = Annotated[
    list[Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]],
    Field(min_length=APPEARANCE_SIZE, max_length=APPEARANCE_SIZE),
]


class Observation(Schema):
    """One detection: the camera, its capture time (Unix seconds on the service's clock), and
    either a distorted pixel with its uncertainty (sigma_px, or a 2x2 covariance px^2; 1 px
    when neither) and the height (m) of the point it measures, or a detector's box
    [x0, y0, x1, y1] (distorted px) with its score (0-1) and the sides cut by the image's edge
    or a mask, whose foot point (bottom centre, on the floor) and covariance the service
    measures (core.localization.box_foot); its kind where the sender knows it (a box: person
    unless said), and the target's label only when the sender knows which target it is."""

    camera_id: Id
    t: Finite
    pixel: Pixel | None = None
    sigma_px: Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)] | None = None
    cov: Cov2 | None = None
    box: Box | None = Field(None, description="[x0, y0, x1, y1], distorted pixels.")
    score: Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)] | None = Field(
        None,
        description="The detector's score of the box; below the camera's threshold it is dropped.",
    )
    cut: Annotated[list[BoxSide], Field(max_length=4)] | None = Field(
        None,
        description="Sides of the box cut by the image's edge or a mask; a cut bottom is "
        "stored but gives no floor position.",
    )
    appearance: Appearance | None = Field(
        None,
        description=f"The box's look: {APPEARANCE_SIZE} hue-saturation histogram bins of its "
        "upper and lower body (core.localization.appearance.box_appearance), summing to at "
        "most 1; the tracker compares it with what each target looked like in this camera.",
    )
    kind: Kind | None = None
    target: Annotated[str, Field(min_length=1, max_length=200)] | None = None
    height: Annotated[float, Field(ge=-10, le=10, allow_inf_nan=False)] = 0.0

    @field_validator("box")
    @classmethod
    def _ordered_box(cls, box: list[float] | None) -> list[float] | None:
        if box is not None and (box[0] >= box[2] or box[1] >= box[3]):
            raise ValueError(f"a box is [x0, y0, x1, y1] with x0 < x1 and y0 < y1, got {box}")
        return box

    @model_validator(mode="after")
    def _one_uncertainty(self) -> Observation:
        if (self.pixel is None) == (self.box is None):
            raise ValueError(
                "give either pixel (with its height) or box, not both"
                if self.pixel is not None
                else "an observation needs a pixel or a box; it has neither"
            )
        if self.box is None and (
            self.score is not None or self.cut is not None or self.appearance is not None
        ):
            raise ValueError(
                "score, cut and appearance describe a box; send them with box, not pixel"
            )
        if self.appearance is not None and sum(self.appearance) > 1.0 + 1e-3:
            raise ValueError(
                "an appearance is histograms that sum to at most 1 "
                f"(core.localization.appearance), got {sum(self.appearance):.6g}"
            )
        if self.box is not None:
            if self.sigma_px is not None or self.cov is not None:
                raise ValueError(
                    "a box's foot covariance comes from its size (core.localization.box_foot); "
                    "drop sigma_px and cov"
                )
            if self.height != 0.0:
                raise ValueError("a box's foot point is on the floor: drop height")
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
