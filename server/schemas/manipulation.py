"""Schemas of mobile manipulation: arms on robots, hand-eye calibration runs and their history,
robot tasks (fetch)."""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, Field, model_validator

from core.manipulation import default_arm
from server.schemas.calibration import (
    MAX_POINTS_PER_VIEW,
    MAX_VIEWS,
    HandEyeMethodRow,
    HandEyeRunResult,
    Point2,
    Point3,
)
from server.schemas.common import (
    ABSENT,
    Distortion,
    Id,
    Matrix3,
    Name,
    ReadSchema,
    RigidTransform,
    Schema,
    UtcDatetime,
)

# core.manipulation.METHODS, spelled out for the OpenAPI schema.
HandEyeMethod = Literal["tsai", "park", "daniilidis", "andreff", "two-group"]

# An arm longer than this (a link offset in metres) is a unit slip, not a robot arm.
MAX_LINK_M = 10.0
# Joint angles (DH twist, offset, limits, home) beyond two turns either way are a unit slip
# (degrees typed as radians).
MAX_ANGLE_RAD = 4.0 * math.pi

Length = Annotated[float, Field(allow_inf_nan=False, ge=-MAX_LINK_M, le=MAX_LINK_M)]
Angle = Annotated[float, Field(allow_inf_nan=False, ge=-MAX_ANGLE_RAD, le=MAX_ANGLE_RAD)]
Lengths6 = Annotated[list[Length], Field(min_length=6, max_length=6)]
Angles6 = Annotated[list[Angle], Field(min_length=6, max_length=6)]


def _joint_range(pair: list[float]) -> list[float]:
    if not pair[0] < pair[1]:
        raise ValueError(
            f"a joint's lower limit ({pair[0]:g}) must be below its upper ({pair[1]:g})"
        )
    return pair


JointRange = Annotated[list[Angle], Field(min_length=2, max_length=2), AfterValidator(_joint_range)]
JointLimits = Annotated[
    list[JointRange],
    Field(min_length=6, max_length=6, description="Six [lower, upper] joint limits, radians."),
]


def _twin_arm_values() -> dict[str, Any]:
    arm = default_arm()
    return {
        "dh": {
            "a": arm.a.tolist(),
            "d": arm.d.tolist(),
            "alpha": arm.alpha.tolist(),
            "offset": arm.offset.tolist(),
        },
        "limits": arm.limits.tolist(),
        "tool": arm.tool.tolist(),
        "home": arm.home.tolist(),
    }


TWIN_ARM = _twin_arm_values()


class DHParameters(Schema):
    """Standard (distal) Denavit-Hartenberg parameters of six revolute joints: link i is
    Rz(q_i + offset_i) Tz(d_i) Tx(a_i) Rx(alpha_i)."""

    a: Lengths6 = Field(description="Link lengths, metres.")
    d: Lengths6 = Field(description="Link offsets along z, metres.")
    alpha: Angles6 = Field(description="Link twists, radians.")
    offset: Angles6 = Field(
        default_factory=lambda: [0.0] * 6, description="Joint zero offsets, radians."
    )


def _default_dh() -> DHParameters:
    return DHParameters(**TWIN_ARM["dh"])


class ArmCreate(Schema):
    """An arm on a robot. Every kinematic field left out is the twin's arm's (a Puma 560
    geometry with a 0.12 m gripper, its shoulder 0.80 m above the floor)."""

    robot_id: Id
    name: Name
    dh: DHParameters = Field(default_factory=_default_dh)
    limits: JointLimits = Field(default_factory=lambda: TWIN_ARM["limits"])
    tool: RigidTransform = Field(
        default_factory=lambda: TWIN_ARM["tool"],
        description="T_flange_ee: the end effector (fingertip centre) in the flange frame.",
    )
    home: Angles6 = Field(
        default_factory=lambda: TWIN_ARM["home"],
        description="A configuration inside the limits away from singularities, radians.",
    )
    T_robot_arm: RigidTransform = Field(
        default_factory=lambda: [
            [1.0, 0.0, 0.0, 0.05],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.80],
            [0.0, 0.0, 0.0, 1.0],
        ],
        description="The arm's base frame in the robot's base frame (x forward, z up, on the "
        "floor under the base centre).",
    )
    camera_id: Id | None = Field(None, description="The eye-in-hand camera.")
    T_ee_camera: RigidTransform | None = Field(
        None, description="Hand-eye transform: the camera (OpenCV frame) in the end effector's."
    )


class ArmUpdate(Schema):
    """Fields to change; setting T_ee_camera by hand detaches the arm from its hand-eye run."""

    robot_id: Id = ABSENT
    name: Name = ABSENT
    dh: DHParameters = ABSENT
    limits: JointLimits = ABSENT
    tool: RigidTransform = ABSENT
    home: Angles6 = ABSENT
    T_robot_arm: RigidTransform = ABSENT
    camera_id: Id | None = None
    T_ee_camera: RigidTransform | None = None


class ArmRead(ReadSchema):
    id: int
    robot_id: int
    name: str
    dh: dict[str, list[float]]
    limits: list[list[float]]
    tool: list[list[float]]
    home: list[float]
    T_robot_arm: list[list[float]]
    camera_id: int | None
    T_ee_camera: list[list[float]] | None
    hand_eye_run_id: int | None
    closed_form: bool = Field(
        description="The geometry is the Puma type the closed-form inverse kinematics solves "
        "(needed by the twin's hand-eye views and fetch tasks)."
    )
    created_at: UtcDatetime
    updated_at: UtcDatetime


class HandEyeCalibrationRead(ReadSchema):
    """One entry of an arm's hand-eye history."""

    id: int
    arm_id: int
    calibration_run_id: int | None
    T_ee_camera: list[list[float]]
    rotation_std_deg: float
    translation_std_m: float
    rms_px: float | None
    method: str
    created_at: UtcDatetime


# Hand-eye calibration runs

PoseList = Annotated[list[RigidTransform], Field(min_length=3, max_length=MAX_VIEWS)]


class HandEyeTwinOptions(Schema):
    views: int = Field(15, ge=3, le=60, description="Views of the table's chessboard.")
    sigma_px: float = Field(
        0.5, ge=0, le=5, allow_inf_nan=False, description="Pixel noise added, per axis."
    )
    rendered: bool = Field(
        True,
        description="Detect the corners in rendered images (about 1 s a view); false: the "
        "corners' true projections plus the noise (milliseconds).",
    )
    seed: int | None = Field(
        None, ge=0, le=2**31 - 1, description="Seed of the arm's views; drawn when absent."
    )


class HandEyeRunCreate(Schema):
    """Hand-eye calibration of an arm's eye-in-hand camera (X = T_ee_camera).

    source "twin": the twin's arm shows its camera a chessboard on the dining table from
    `twin.views` poses (as the `hand-eye` scenario does) and the run calibrates from the joint
    readings and the images; needs the service's digital twin. source "poses": the pose pairs
    of your own arm: T_base_ee (forward kinematics, end effector in the arm's base frame) and
    T_cam_target (the target in the camera frame), one of each per view, as OpenCV's
    calibrateHandEye takes them; with the target's object_points, every view's image_points
    and K (default: the arm's camera's), X is refined by reprojection error."""

    kind: Literal["hand-eye"]
    arm_id: Id
    source: Literal["twin", "poses"] = "twin"
    method: HandEyeMethod = Field("park", description="Linear method (refined after).")
    refine: bool = Field(
        True, description="Refine by reprojection error when the views' pixels are known."
    )
    twin: HandEyeTwinOptions = Field(default_factory=HandEyeTwinOptions)
    T_base_ee: PoseList | None = None
    T_cam_target: PoseList | None = None
    object_points: (
        Annotated[list[Point3], Field(min_length=4, max_length=MAX_POINTS_PER_VIEW)] | None
    ) = Field(None, description="The target's points (M x 3, metres, target frame).")
    image_points: (
        Annotated[
            list[Annotated[list[Point2], Field(min_length=4, max_length=MAX_POINTS_PER_VIEW)]],
            Field(min_length=3, max_length=MAX_VIEWS),
        ]
        | None
    ) = Field(None, description="Per view, the M target points' pixels.")
    K: Matrix3 | None = None
    dist: Distortion | None = None

    @model_validator(mode="after")
    def _source_inputs(self) -> HandEyeRunCreate:
        if self.source == "poses":
            missing = [k for k in ("T_base_ee", "T_cam_target") if getattr(self, k) is None]
            if missing:
                raise ValueError(
                    f"source 'poses' needs {' and '.join(missing)}: one 4x4 pose per view"
                )
            if "twin" in self.model_fields_set:
                raise ValueError(
                    "twin options given with source 'poses'; they choose the twin's views, "
                    "which uploaded pose pairs replace"
                )
        else:
            given = [
                k
                for k in ("T_base_ee", "T_cam_target", "object_points", "image_points", "K")
                if getattr(self, k) is not None
            ]
            if given:
                raise ValueError(
                    f"{', '.join(given)} given with source 'twin', which makes its own views; "
                    "use source 'poses' to calibrate from them"
                )
        return self


# Tasks

TaskStatus = Literal["queued", "running", "succeeded", "failed", "interrupted"]


class FetchTaskCreate(Schema):
    """Fetch a marked box from the dining table with an arm, on the twin: each episode places
    the box at random (position, yaw; the robot knows its pose 5 cm / 0.15 rad off), starts the
    robot at random in the kitchen corridor, and runs the switching controller: approach under
    the gaze constraint, switch, look then move, grasp (the gripper closes on the box), lift
    and carry; every eye-in-hand image is rendered by the twin. The arm's applied
    hand-eye transform is used; without one the task calibrates it first (15 views, refined)."""

    kind: Literal["fetch"]
    arm_id: Id
    object: Id | Annotated[str, Field(min_length=1, max_length=200)] | None = Field(
        None,
        description="An object of the twin's semantic map (GET /maps/semantic), by its id or "
        "its name: the box is fetched at the pose the map holds. Absent: a box placed at "
        "random on the dining table.",
    )
    episodes: int = Field(
        1, ge=1, le=100, description="Fetches to run (about 5 s each: every image is rendered)."
    )
    sigma_px: float = Field(0.5, ge=0, le=5, allow_inf_nan=False, description="Pixel noise.")
    seed: int | None = Field(None, ge=0, le=2**31 - 1, description="Drawn when absent.")


class EpisodePhase(ReadSchema):
    name: str
    ok: bool


class FetchEpisodeRead(ReadSchema):
    """One fetch: its outcome, the phases it went through (the last one failed when it did),
    the final end-effector error against the twin's true grasp pose, and its diagnostics."""

    success: bool
    phases: list[EpisodePhase]
    position_error_mm: float | None
    rotation_error_deg: float | None
    time_s: float = Field(description="Simulated seconds.")
    visible_fraction: float = Field(description="Share of approach steps the mark was seen.")
    switches: int
    looks: int
    reason: str
    gripper_opening_mm: float | None = Field(
        None, description="Where the fingers stopped when the gripper closed (the box: 115 mm)."
    )
    frames: int = Field(0, description="Eye-in-hand images rendered and searched.")


class FetchHandEye(ReadSchema):
    """Where a fetch task's hand-eye transform came from ('arm': the arm's applied one;
    'calibrated': calibrated for the task) and its errors against the twin's truth."""

    source: str
    rotation_error_deg: float
    translation_error_mm: float


class FetchResult(ReadSchema):
    episodes: int = Field(description="Episodes finished so far.")
    planned: int
    successes: int
    success_rate: float | None
    position_error_m: float | None = Field(description="Median over successes, metres.")
    rotation_error_deg: float | None = Field(description="Median over successes, degrees.")
    time_s: float | None = Field(description="Median simulated time per episode, seconds.")
    failures: dict[str, int]
    hand_eye: FetchHandEye
    seed: int
    per_episode: list[FetchEpisodeRead]


class TaskRead(ReadSchema):
    id: int
    kind: str
    status: TaskStatus
    arm_id: int | None
    inputs: dict[str, Any]
    phase: str | None = Field(description="What the task is doing now (or last did).")
    progress: float | None = Field(description="Share done, 0 to 1.")
    result: FetchResult | None
    error: str | None
    created_at: UtcDatetime
    updated_at: UtcDatetime
    started_at: UtcDatetime | None
    finished_at: UtcDatetime | None


__all__ = [
    "ArmCreate",
    "ArmRead",
    "ArmUpdate",
    "FetchTaskCreate",
    "HandEyeCalibrationRead",
    "HandEyeMethodRow",
    "HandEyeRunCreate",
    "HandEyeRunResult",
    "TaskRead",
]
