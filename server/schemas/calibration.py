"""Schemas of calibration runs: inline correspondences in, status and result out."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field, model_validator

from server.schemas.common import Finite, Id, PixelCount, ReadSchema, Schema, UtcDatetime
from server.schemas.twin import NetworkRunResult

# Lens models of core.calibration.calibrate_camera, by the coefficients they estimate.
DistortionModel = Literal["none", "k1", "k1k2", "k1k2p1p2", "k1k2p1p2k3"]
RunStatus = Literal["queued", "running", "succeeded", "failed", "interrupted"]

Point2 = Annotated[list[Finite], Field(min_length=2, max_length=2)]
Point3 = Annotated[list[Finite], Field(min_length=3, max_length=3)]
MAX_VIEWS = 200
MAX_POINTS_PER_VIEW = 10_000


class IntrinsicsOptions(Schema):
    skew: bool = Field(False, description="Estimate the skew gamma = K[0][1].")
    distortion: DistortionModel = Field("k1k2p1p2", description="Distortion coefficients fitted.")


class IntrinsicsRunCreate(Schema):
    """Intrinsic calibration from planar correspondences (Zhang): per view, the pattern's points
    on its plane (N x 3, Z = 0, any length unit) and their pixels (N x 2)."""

    kind: Literal["intrinsics"]
    camera_id: Id
    image_size: Annotated[list[PixelCount], Field(min_length=2, max_length=2)] = Field(
        description="[width, height] of the images, pixels."
    )
    object_points: Annotated[
        list[Annotated[list[Point3], Field(min_length=1, max_length=MAX_POINTS_PER_VIEW)]],
        Field(min_length=1, max_length=MAX_VIEWS),
    ]
    image_points: Annotated[
        list[Annotated[list[Point2], Field(min_length=1, max_length=MAX_POINTS_PER_VIEW)]],
        Field(min_length=1, max_length=MAX_VIEWS),
    ]
    options: IntrinsicsOptions = Field(default_factory=IntrinsicsOptions)

    @model_validator(mode="after")
    def _views_match(self) -> IntrinsicsRunCreate:
        if len(self.object_points) != len(self.image_points):
            raise ValueError(
                f"object_points has {len(self.object_points)} views but image_points has "
                f"{len(self.image_points)}; give one list of each per view"
            )
        for i, (obj, img) in enumerate(zip(self.object_points, self.image_points, strict=True)):
            if len(obj) != len(img):
                raise ValueError(
                    f"view {i}: {len(obj)} object points but {len(img)} image points; "
                    "they must correspond one to one"
                )
        return self


class CalibrationResult(ReadSchema):
    """What a successful intrinsic calibration produced, with its diagnostics."""

    K: list[list[float]]
    dist: list[float] = Field(description="OpenCV order k1, k2, p1, p2, k3.")
    rms: float = Field(description="RMS reprojection error over all points, pixels.")
    std_intrinsics: dict[str, float] | None = Field(
        None, description="Standard deviation of each estimated parameter (fx, fy, cx, ...)."
    )
    per_view_rms: list[float] = Field(description="RMS reprojection error of each view, pixels.")
    image_size: list[int]
    views_used: list[int] | None = Field(
        None, description="Indices of the uploaded images in which the pattern was found."
    )


class CalibrationRunRead(ReadSchema):
    id: int
    kind: str
    source: Literal["correspondences", "images", "twin"]
    status: RunStatus
    camera_id: int | None
    options: dict[str, Any]
    result: CalibrationResult | NetworkRunResult | None
    error: str | None
    created_at: UtcDatetime
    updated_at: UtcDatetime
    started_at: UtcDatetime | None
    finished_at: UtcDatetime | None
