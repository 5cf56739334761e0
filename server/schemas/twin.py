"""Schemas of the digital twin's control and of the network calibration run."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field

from server.schemas.common import ReadSchema, Schema


class TwinState(ReadSchema):
    enabled: bool
    running: bool = False
    paused: bool = False
    scene: str | None = None
    sim_time: float | None = None
    steps: int = 0
    rate_hz: float | None = None
    robot: dict[str, float] | None = None
    people: list[dict[str, float]] = Field(default_factory=list)
    robot_error_rms_m: float | None = Field(
        None, description="RMS distance of the located robot from the twin's truth, metres."
    )
    cameras: dict[str, int] = Field(default_factory=dict)


class TwinRate(Schema):
    rate_hz: float = Field(gt=0, le=30, allow_inf_nan=False)


class Scenario(ReadSchema):
    name: str
    description: str


class NetworkOptions(Schema):
    seed: int = Field(0, ge=0, le=2**31 - 1)
    target: Literal["marker"] = "marker"
    spacing: float = Field(0.3, ge=0.15, le=2.0, description="Stops' grid spacing, metres.")


class NetworkRunCreate(Schema):
    """Calibrate every twin camera by driving the robot's marker over the floor."""

    kind: Literal["network"]
    options: NetworkOptions = Field(default_factory=NetworkOptions)


class CameraErrors(ReadSchema):
    focal_pct: float = Field(description="Focal length error, percent of the truth (signed).")
    position_m: float = Field(description="Optical centre position error, metres.")
    rotation_deg: float = Field(description="Orientation error (angle of R_est R_true^T), deg.")


class NetworkCameraResult(ReadSchema):
    name: str
    camera_id: int | None = None
    K: list[list[float]]
    dist: list[float]
    T_world_camera: list[list[float]]
    std: dict[str, Any] = Field(description="Standard deviations of f (px), rvec (rad), t (m).")
    rms: float = Field(description="RMS reprojection error of its detections, pixels.")
    poses_seen: int
    errors: CameraErrors = Field(description="Against the twin's true camera.")
    image_size: list[int]


class NetworkRunResult(ReadSchema):
    """What a network calibration produced: every calibrated camera, and those left out."""

    kind: Literal["network"]
    target: str
    poses: int
    detections: int
    rms: float
    cameras: list[NetworkCameraResult]
    rejected: list[dict[str, Any]]
