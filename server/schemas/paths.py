"""Schemas of the paths (planning requests, planned paths, their follow tasks) and of the
projector calibration runs (spec 03); a run's result is read through
server.schemas.calibration's CalibrationRunRead, which covers every kind."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, Field

from server.schemas.common import Id, ReadSchema, Schema, UtcDatetime

# Floor coordinates beyond a kilometre are a typing slip, not a home.
Coordinate = Annotated[float, Field(ge=-1000.0, le=1000.0, allow_inf_nan=False)]
FloorPoint = Annotated[
    list[Coordinate], Field(min_length=2, max_length=2, description="World (x, y), metres.")
]
Law = Literal["state_feedback", "adaptive", "proportional"]


class PathCreate(Schema):
    """Plan a path on the space's floor plan, optionally drawn by one of its projectors."""

    space_id: Id
    start: FloorPoint
    goal: FloorPoint
    projector_id: Id | None = Field(
        None, description="Draw the path with this projector: its joint trajectory is returned."
    )
    robot_radius: Annotated[float, Field(ge=0.0, le=2.0, allow_inf_nan=False)] | None = Field(
        None,
        description="Metres the robot must keep from walls and furniture. Default: the base "
        "radius of the space's robot (kinematic_model.base_radius), else 0.2 m.",
    )
    # At least 5 cm/s: the trajectory's samples grow as the inverse of the speed.
    spot_speed: Annotated[float, Field(ge=0.05, le=2.0, allow_inf_nan=False)] = Field(
        0.3, description="Cruising speed of the projected spot, m/s (0.05 to 2)."
    )


class FollowCreate(Schema):
    """Start the follow task of a path on the digital twin."""

    law: Law = Field(
        "state_feedback",
        description="state_feedback (nonlinear state-error feedback), adaptive (adaptive "
        "compensation of the spot's unknown velocity) or proportional (the baseline).",
    )
    seed: Annotated[int, Field(ge=0, le=2**31 - 1)] | None = Field(
        None,
        description="Seed of the twin's noise (slip, pixels, missed frames) and of its "
        "projector's mounting error. Default: the service's twin seed.",
    )


class JointTrajectoryRead(BaseModel):
    """The projector's joint trajectory, sampled every `dt_s` seconds."""

    dt_s: float
    duration_s: float
    t: list[float] = Field(description="Seconds from the start.")
    q: list[list[float]] = Field(description="(pan, tilt) radians per sample.")
    spot: list[list[float]] = Field(description="The planned floor spot (x, y) m per sample.")


class FollowResult(BaseModel):
    """A finished follow's metrics against the twin: the tracking error's RMS, maximum and
    steady-state value (m; null when it never settled), when it finished (s), the times the
    camera lost the spot, the trajectory's duration (s), how far the twin's projector drew
    from the planned spots (m), and the floor camera's rate (Hz) and latency (s)."""

    rms_m: float
    max_m: float
    steady_m: float | None
    finish_s: float | None
    lost_events: int
    duration_s: float
    drawing_error_max_m: float
    camera_hz: float
    latency_s: float


class FollowRead(BaseModel):
    """The follow task of a path: status (idle, running, succeeded, failed, interrupted),
    law, seed, progress (0..1 of the trajectory's duration), the metrics when it ended and the
    series, 5 Hz, so far while it runs (renewed every 0.5 s) and whole once it ended: `t` s,
    `error_m` m (tracking error), `x`, `y` m and `theta` rad (the robot's pose), `spot_x`,
    `spot_y` m (the laser spot on the floor), against the twin."""

    status: str
    law: str | None
    seed: int | None
    progress: float | None
    result: FollowResult | None
    series: dict[str, list[float]] | None
    error: str | None
    started_at: UtcDatetime | None
    finished_at: UtcDatetime | None


class PathSummary(ReadSchema):
    """A path in a listing (without its trajectory and error series)."""

    id: int
    space_id: int
    projector_id: int | None
    start: list[float]
    goal: list[float]
    length_m: float
    follow_status: str
    created_at: UtcDatetime


class PathRead(BaseModel):
    """A planned path: its points (N, 2) world metres from start to goal, length, the planning
    inputs, the projector's joint trajectory (null without a projector) and the follow task."""

    id: int
    space_id: int
    projector_id: int | None
    start: list[float]
    goal: list[float]
    points: list[list[float]]
    length_m: float
    robot_radius_m: float
    resolution_m: float
    floor_plan: str = Field(description="Which floor plan the path was planned on.")
    spot_speed_mps: float | None
    projector_model: dict[str, Any] | None = Field(
        description="The pan-tilt model that drew it: T_world_base, theta (joint zero offsets, "
        "rad), joint limits, rates and accelerations; null without a projector."
    )
    trajectory: JointTrajectoryRead | None
    follow: FollowRead
    created_at: UtcDatetime


class RoomOutlineRead(BaseModel):
    name: str
    polygon: list[list[float]] = Field(description="Corners (x, y), metres.")


class WallSpanRead(BaseModel):
    """A solid span of a wall, between its doors."""

    start: list[float]
    end: list[float]
    thickness: float


class FurnitureRead(BaseModel):
    name: str
    footprint: list[list[float]] = Field(description="Its 4 corners (x, y) on the floor, metres.")


class FloorPlanDrawing(BaseModel):
    """A floor plan as drawn on a map: which plan, its room polygons, the solid spans of its
    walls and its furniture footprints, world metres."""

    floor_plan: str
    rooms: list[RoomOutlineRead]
    walls: list[WallSpanRead]
    furniture: list[FurnitureRead]


class FloorPlanRead(BaseModel):
    """The floor plan paths are planned on in a space (its drawing), with the clearance the
    planner keeps (robot radius + margin, m)."""

    space_id: int
    floor_plan: str
    rooms: list[RoomOutlineRead]
    walls: list[WallSpanRead]
    furniture: list[FurnitureRead]
    robot_radius_m: float
    clearance_m: float


# Projector calibration runs (kind "projector")


class ProjectorRunCreate(Schema):
    """Calibrate a projector's mount (and its tilt offset) on the digital twin: the twin's
    projector points its beam at spots over the living room, the space's calibrated ceiling
    cameras locate each spot on the floor, and the sparse LM fits T_world_projector to the
    commanded angles (core.calibration.calibrate_projector). The projector must be in the
    twin's home."""

    kind: Literal["projector"]
    projector_id: Id
    camera_ids: list[Id] | None = Field(
        None,
        max_length=64,
        description="The cameras that locate the spots. Default: every camera of the "
        "projector's space with intrinsics and a pose.",
    )
    seed: Annotated[int, Field(ge=0, le=2**31 - 1)] | None = Field(
        None, description="Seed of the twin's projector error and the cameras' noise."
    )
    images: bool = Field(
        True,
        description="Detect the spots in rendered frames (about 10 s); false: project them "
        "through the cameras' true lenses with 0.5 px noise (a second).",
    )


class ProjectorCalibrationRead(ReadSchema):
    """One entry of a projector's calibration history."""

    id: int
    projector_id: int
    calibration_run_id: int | None
    T_world_projector: list[list[float]]
    tilt_offset: float
    rms_m: float
    spots: int
    created_at: UtcDatetime
