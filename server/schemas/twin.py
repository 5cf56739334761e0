"""Schemas of the digital twin's control and of the network calibration run."""

from __future__ import annotations

from typing import Literal

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
    stops: int = Field(32, ge=6, le=200, description="Stops of the robot's planned drive.")
    study: bool = Field(
        True, description="Also report the accuracy against drive length and pixel noise."
    )


class NetworkRunCreate(Schema):
    """Calibrate every twin camera by driving the robot's marker over the floor."""

    kind: Literal["network"]
    options: NetworkOptions = Field(default_factory=NetworkOptions)
