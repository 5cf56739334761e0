"""Schemas of the registry: spaces, rooms, cameras, projectors, robots, landmarks."""

from __future__ import annotations

import json
from typing import Annotated, Any, ClassVar, Literal

import numpy as np
from pydantic import AfterValidator, Field, model_validator
from shapely import Polygon as ShapelyPolygon
from shapely.validation import explain_validity

from core.errors import IntspaceError
from server.schemas.common import (
    ABSENT,
    Distortion,
    Finite,
    Id,
    Matrix3,
    Name,
    PixelCount,
    ReadSchema,
    RigidTransform,
    Schema,
    Text,
    UtcDatetime,
    Vec2,
    Vec3,
    Vec4,
)
from server.services.cameras import network_camera
from server.services.poses import pose_from_position_quaternion


def _simple_polygon(polygon: list[list[float]]) -> list[list[float]]:
    # shapely (GEOS) judges validity: a self-intersecting ring or a zero area is no floor.
    shape = ShapelyPolygon(polygon)
    if not shape.is_valid:
        raise ValueError(f"must be a simple polygon: {explain_validity(shape)}")
    if not shape.area > 0:
        raise ValueError("must enclose a positive area")
    return polygon


Polygon = Annotated[
    list[Vec2],
    Field(
        min_length=3,
        max_length=10_000,
        description="Floor polygon [[x, y], ...] in metres: simple (no self-intersection), "
        "positive area",
    ),
    AfterValidator(_simple_polygon),
]


# Free-form JSON nests at most this deep: 500 levels stored made every later read a 500 (the
# serialiser's recursion limit), and no kinematic description needs more than a few.
MAX_JSON_DEPTH = 32
MAX_JSON_CHARS = 100_000


def json_depth(value: Any) -> int:
    """Return how deep `value` (dicts and lists of JSON values) nests; a scalar is 0. Iterative,
    so that any depth is measured without recursion."""
    deepest = 0
    stack: list[tuple[Any, int]] = [(value, 0)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, dict):
            children: Any = item.values()
        elif isinstance(item, list):
            children = item
        else:
            continue
        depth += 1
        deepest = max(deepest, depth)
        if deepest > MAX_JSON_DEPTH:
            return deepest
        stack.extend((child, depth) for child in children)
    return deepest


def _json_document(value: dict[str, Any]) -> dict[str, Any]:
    # Strict JSON: bounded depth and size, no NaN or infinity, no NUL (PostgreSQL refuses both).
    if json_depth(value) > MAX_JSON_DEPTH:
        raise ValueError(f"must nest at most {MAX_JSON_DEPTH} levels of objects and arrays")
    try:
        text = json.dumps(value, allow_nan=False)
    except ValueError as exc:
        raise ValueError("must be finite JSON (no NaN or infinity)") from exc
    if len(text) > MAX_JSON_CHARS:
        raise ValueError(f"must be at most {MAX_JSON_CHARS} characters of JSON")
    if "\\u0000" in text:
        raise ValueError("must not contain NUL characters")
    return value


JsonDocument = Annotated[dict[str, Any], AfterValidator(_json_document)]


# Spaces


class SpaceCreate(Schema):
    name: Name
    description: Text = ""


# Update schemas: an absent field is left unchanged; null is refused where the column is required
# (the field's type is not optional, only its default is None).


class SpaceUpdate(Schema):
    name: Name = ABSENT
    description: Text = ABSENT


class SpaceRead(ReadSchema):
    id: int
    name: str
    description: str
    created_at: UtcDatetime
    updated_at: UtcDatetime


# Rooms


class RoomCreate(Schema):
    space_id: Id
    name: Name
    polygon: Polygon


class RoomUpdate(Schema):
    space_id: Id = ABSENT
    name: Name = ABSENT
    polygon: Polygon = ABSENT


class RoomRead(ReadSchema):
    id: int
    space_id: int
    name: str
    polygon: list[list[float]]
    created_at: UtcDatetime
    updated_at: UtcDatetime


# Cameras


class _PoseInput(Schema):
    """A pose given either as T_<world>_<device> (4x4) or as position + quaternion (x, y, z, w)."""

    position: Vec3 | None = Field(None, description="Device origin in the world frame, metres.")
    quaternion_xyzw: Vec4 | None = Field(None, description="Device-to-world rotation (x, y, z, w).")

    pose_field: ClassVar[str] = "T_world_camera"

    @model_validator(mode="after")
    def _pose_from_parts(self) -> _PoseInput:
        given = (self.position is not None, self.quaternion_xyzw is not None)
        if given == (False, False):
            return self
        if given != (True, True):
            raise ValueError("position and quaternion_xyzw must be given together")
        if getattr(self, self.pose_field) is not None:
            raise ValueError(f"give either {self.pose_field} or position + quaternion_xyzw")
        assert self.position is not None and self.quaternion_xyzw is not None
        T = pose_from_position_quaternion(self.position, self.quaternion_xyzw)
        setattr(self, self.pose_field, T)
        self.position = None
        self.quaternion_xyzw = None
        return self

    def changes(self) -> dict[str, Any]:
        """Return the fields the client set, the pose converted to its 4x4 matrix."""
        data = self.model_dump(exclude_unset=True, exclude={"position", "quaternion_xyzw"})
        pose = getattr(self, self.pose_field)
        if pose is not None:
            data[self.pose_field] = pose
        return data


# A plausible camera model: focal lengths between 0.05 and 100 image sizes (a fisheye's is about
# a third of its width, a long telephoto's tens of widths), the principal point within half an
# image of it, skew at most a tenth of fx, distortion coefficients below 1e4 in magnitude.
FOCAL_RANGE = (0.05, 100.0)
MAX_SKEW_RATIO = 0.1
MAX_DISTORTION = 1e4


def camera_model_problem(
    K: list[list[float]] | None, dist: list[float] | None, width: int, height: int
) -> tuple[str, str] | None:
    """Return (field, reason) when the camera model (K, dist) of a width x height image is
    implausible or one core cannot use; None when it is fine (or K is not given)."""
    if dist is not None and any(abs(d) > MAX_DISTORTION for d in dist):
        return "dist", f"distortion coefficients must be below {MAX_DISTORTION:g} in magnitude"
    if K is None:
        return None
    size = max(width, height)
    lo, hi = FOCAL_RANGE[0] * size, FOCAL_RANGE[1] * size
    for name, value in (("K.0.0", K[0][0]), ("K.1.1", K[1][1])):
        if not lo <= value <= hi:
            return name, (
                f"focal length {value:g} px is implausible for a {width}x{height} image: give "
                f"{lo:g} to {hi:g} px ({FOCAL_RANGE[0]:g} to {FOCAL_RANGE[1]:g} image sizes)"
            )
    for name, value, extent in (("K.0.2", K[0][2], width), ("K.1.2", K[1][2], height)):
        if not -0.5 * extent <= value <= 1.5 * extent:
            return name, (
                f"principal point coordinate {value:g} px is more than half an image outside "
                f"the {width}x{height} image"
            )
    if abs(K[0][1]) > MAX_SKEW_RATIO * K[0][0]:
        return "K.0.1", f"skew {K[0][1]:g} px exceeds {MAX_SKEW_RATIO:g} fx"
    try:
        # Through the adapter the localisation reads cameras with (at any pose): refuse here
        # what it could not use later.
        fields = {"K": K, "dist": dist, "T_world_camera": np.eye(4)}
        network_camera({"name": "", "width": width, "height": height, **fields})
    except (IntspaceError, ArithmeticError, ValueError) as exc:
        return ("dist" if "dist" in str(exc) else "K"), str(exc)
    return None


ScoreThreshold = Annotated[
    float,
    Field(
        ge=0,
        le=1,
        allow_inf_nan=False,
        description="A detector's boxes scored below this are dropped at ingest.",
    ),
]


class CameraCreate(_PoseInput):
    name: Name
    width: PixelCount
    height: PixelCount
    space_id: Id | None = None
    K: Matrix3 | None = None
    dist: Distortion | None = None
    T_world_camera: RigidTransform | None = None
    score_threshold: ScoreThreshold = 0.5


class CameraUpdate(_PoseInput):
    name: Name = ABSENT
    width: PixelCount = ABSENT
    height: PixelCount = ABSENT
    space_id: Id | None = None
    K: Matrix3 | None = None
    dist: Distortion | None = None
    T_world_camera: RigidTransform | None = None
    score_threshold: ScoreThreshold | None = None

    @model_validator(mode="after")
    def _threshold_not_cleared(self) -> CameraUpdate:
        if "score_threshold" in self.model_fields_set and self.score_threshold is None:
            raise ValueError("score_threshold is a number from 0 to 1; it cannot be cleared")
        return self


class CameraHeartbeat(Schema):
    """What a camera node reports about a camera every second: its frame rate (frames per
    second received), stalls and reconnects of the stream since the node started, frames the
    detector skipped (newer ones came first), detections dropped while the service was
    unreachable, the node's clock offset to the service (s, added to its clock) and the
    capture time of the newest frame (Unix seconds, service clock; null before the first)."""

    fps: Annotated[float, Field(ge=0, le=10_000, allow_inf_nan=False)]
    stalls: Annotated[int, Field(ge=0)] = 0
    reconnects: Annotated[int, Field(ge=0)] = 0
    dropped: Annotated[int, Field(ge=0)] = 0
    dropped_detections: Annotated[int, Field(ge=0)] = 0
    clock_offset_s: Annotated[float, Field(ge=-1e9, le=1e9, allow_inf_nan=False)] = 0.0
    last_frame_t: Finite | None = None


class CameraHealth(ReadSchema):
    """A camera's health from its node's heartbeats: online (frames coming), stalled (the
    node reports but no frame for 2 s or two frame periods, the longer), offline (no heartbeat
    for 5 s, or none yet); since when (Unix seconds; null when never seen); the latest
    heartbeat's counters."""

    status: Literal["online", "stalled", "offline"]
    since: float | None = None
    fps: float | None = None
    stalls: int | None = None
    reconnects: int | None = None
    dropped: int | None = None
    dropped_detections: int | None = None
    clock_offset_s: float | None = None
    last_frame_t: float | None = None
    last_heartbeat: float | None = Field(default=None, description="When the service received it.")


class CameraRead(ReadSchema):
    id: int
    name: str
    width: int
    height: int
    space_id: int | None
    K: list[list[float]] | None
    dist: list[float] | None
    T_world_camera: list[list[float]] | None
    status: Literal["uncalibrated", "nominal", "calibrated"]
    calibration_run_id: int | None
    score_threshold: float = 0.5
    created_at: UtcDatetime
    updated_at: UtcDatetime
    health: CameraHealth | None = Field(
        None, description="From its camera node's heartbeats (POST /cameras/{id}/heartbeat)."
    )


class CameraCalibrationRead(ReadSchema):
    """One entry of a camera's calibration history."""

    id: int
    camera_id: int
    calibration_run_id: int | None
    K: list[list[float]]
    dist: list[float]
    rms: float | None
    image_width: int
    image_height: int
    created_at: UtcDatetime


# Projectors


class ProjectorCreate(_PoseInput):
    pose_field: ClassVar[str] = "T_world_projector"

    name: Name
    width: PixelCount
    height: PixelCount
    space_id: Id | None = None
    K: Matrix3 | None = None
    dist: Distortion | None = None
    T_world_projector: RigidTransform | None = None


class ProjectorUpdate(_PoseInput):
    pose_field: ClassVar[str] = "T_world_projector"

    name: Name = ABSENT
    width: PixelCount = ABSENT
    height: PixelCount = ABSENT
    space_id: Id | None = None
    K: Matrix3 | None = None
    dist: Distortion | None = None
    T_world_projector: RigidTransform | None = None


class ProjectorRead(ReadSchema):
    id: int
    name: str
    width: int
    height: int
    space_id: int | None
    K: list[list[float]] | None
    dist: list[float] | None
    T_world_projector: list[list[float]] | None
    created_at: UtcDatetime
    updated_at: UtcDatetime


# Robots


class RobotCreate(Schema):
    name: Name
    space_id: Id | None = None
    kinematic_model: JsonDocument = Field(
        default_factory=dict, description="Kinematic description (e.g. DH table), free JSON."
    )
    onboard_camera_id: Id | None = None
    hand_camera_id: Id | None = None
    T_hand_camera: RigidTransform | None = Field(None, description="Hand-eye transform.")


class RobotUpdate(Schema):
    name: Name = ABSENT
    space_id: Id | None = None
    kinematic_model: JsonDocument = ABSENT
    onboard_camera_id: Id | None = None
    hand_camera_id: Id | None = None
    T_hand_camera: RigidTransform | None = None


class RobotRead(ReadSchema):
    id: int
    name: str
    space_id: int | None
    kinematic_model: dict[str, Any]
    onboard_camera_id: int | None
    hand_camera_id: int | None
    T_hand_camera: list[list[float]] | None
    created_at: UtcDatetime
    updated_at: UtcDatetime


# Landmarks

LandmarkKind = Literal["qr", "aruco", "apriltag", "chessboard", "other"]
Payload = Annotated[Text, Field(max_length=4096)]
SizeMetres = Annotated[Finite, Field(gt=0, le=100, description="Printed side length, metres.")]


class LandmarkCreate(Schema):
    kind: LandmarkKind
    payload: Payload = ""
    size_m: SizeMetres
    space_id: Id | None = None
    T_world_landmark: RigidTransform | None = None


class LandmarkUpdate(Schema):
    kind: LandmarkKind = ABSENT
    payload: Payload = ABSENT
    size_m: SizeMetres = ABSENT
    space_id: Id | None = None
    T_world_landmark: RigidTransform | None = None


class LandmarkRead(ReadSchema):
    id: int
    kind: str
    payload: str
    size_m: float
    space_id: int | None
    T_world_landmark: list[list[float]] | None
    created_at: UtcDatetime
    updated_at: UtcDatetime
