"""Schemas of the landmark endpoints: detection results and the maps' observations."""

from __future__ import annotations

from typing import Annotated, Any

import numpy as np
from pydantic import AfterValidator, BaseModel, Field, model_validator

from server.schemas.common import Finite, Id, RigidTransform, Schema, Text

Row6 = Annotated[list[Finite], Field(min_length=6, max_length=6)]


def _covariance(C: list[list[float]]) -> list[list[float]]:
    M = np.asarray(C, dtype=float)
    # Variances of at most 1e6 (rad^2, m^2) and at least 1e-18 (1 nm, 1 nrad): the maps invert
    # and fuse them, which must stay finite.
    if np.abs(M).max() > 1e6:
        raise ValueError("covariance entries must be within +-1e6")
    if not np.allclose(M, M.T, rtol=1e-6, atol=1e-12):
        raise ValueError("the covariance must be symmetric")
    try:
        eig = np.linalg.eigvalsh(M)
    except np.linalg.LinAlgError:
        raise ValueError("the covariance's eigenvalues cannot be computed") from None
    if eig.min() < 1e-18 or eig.max() / eig.min() > 1e15:
        raise ValueError("the covariance must be positive definite and well conditioned")
    return C


Covariance6 = Annotated[
    list[Row6],
    Field(
        min_length=6,
        max_length=6,
        description="6x6 covariance of (rotation vector rad, translation m), row-major",
    ),
    AfterValidator(_covariance),
]


class PoseHypothesisOut(BaseModel):
    """One pose a signpost may have (core.landmarks.ambiguity.PoseHypothesis)."""

    T_cam_mark: list[list[float]] = Field(description="4x4 mark frame in the camera, metres.")
    cov: list[list[float]] = Field(description="6x6 covariance of (rotation vector, t).")
    probability: float = Field(description="Its probability given the image, 0-1.")


class Detection(BaseModel):
    """One landmark found in an image (core.landmarks.detect_landmarks)."""

    kind: str = Field(description='"object" (blue frame) or "signpost" (red rings).')
    outline: list[list[float]] = Field(description="Distorted pixels (N, 2) of the outline.")
    T_cam_mark: list[list[float]] = Field(description="4x4 mark frame in the camera, metres.")
    cov: list[list[float]] = Field(description="6x6 covariance of (rotation vector, t).")
    position: list[float]
    normal: list[float]
    distance_m: float
    record: dict[str, Any] | None = Field(description="The decoded payload, or null.")
    reason: str | None = Field(description="Why it was not decoded, null when decoded.")
    text: str | None = Field(description="The symbol's raw text when one was read.")
    orientation_known: bool
    rms_px: float
    decided: bool = Field(
        True,
        description="Whether the image decides the pose; when not, cov covers both of a "
        "signpost's poses (docs/landmark-poses.md).",
    )
    hypotheses: list[PoseHypothesisOut] = Field(
        default_factory=list,
        description="A signpost's two poses, best first (the first is T_cam_mark), each with "
        "its own covariance and its probability given the image; empty for object marks.",
    )


class DetectResult(BaseModel):
    """The landmarks found in an uploaded image."""

    width: int
    height: int
    camera_id: int | None
    frame_size: float
    ring_size: float
    detections: list[Detection]


class MapObservationIn(Schema):
    """A read landmark to enter the maps: the payload text as read, its pose in the camera
    (T_cam_mark, cov, as POST /landmarks/detect returns them) and the camera's world pose
    (T_world_camera, or camera_id: a registered camera with a pose)."""

    payload: Annotated[Text, Field(min_length=1, max_length=4096)]
    T_cam_mark: RigidTransform
    cov: Covariance6
    camera_id: Id | None = None
    T_world_camera: RigidTransform | None = None
    time: (
        Annotated[Finite, Field(ge=0, le=1e11, description="Unix seconds; default now.")] | None
    ) = None

    @model_validator(mode="after")
    def _one_pose(self) -> MapObservationIn:
        if (self.camera_id is None) == (self.T_world_camera is None):
            raise ValueError("give exactly one of camera_id and T_world_camera")
        return self


class MapObservations(Schema):
    """A batch of read landmarks for one space's maps (default: the first space)."""

    space_id: Id | None = None
    observations: list[MapObservationIn] = Field(min_length=1, max_length=1000)


class MapChange(BaseModel):
    map: str
    mark_id: int
    change: str = Field(description='"added" or "updated".')


class MapUpdate(BaseModel):
    space_id: int
    changes: list[MapChange]
    navigation_edges: int | None


class RouteRead(BaseModel):
    """A shortest route between two rooms through the navigation map's places."""

    space_id: int
    from_room: str
    to_room: str
    places: list[int]
    rooms: list[str]
    length_m: float
    features: dict[str, Any] = Field(description="The route as a GeoJSON-like LineString.")


__all__ = [
    "Covariance6",
    "DetectResult",
    "MapObservationIn",
    "MapObservations",
    "MapUpdate",
    "RouteRead",
]
