"""Schemas of the digital twin's control and of the network calibration run."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from core.sim.scenarios.network import MAX_DRIVE_S
from server.schemas.common import ReadSchema, Schema


class TwinState(ReadSchema):
    enabled: bool
    running: bool = False
    paused: bool = False
    scene: str | None = None
    space_id: int | None = Field(None, description="The space the twin's home is registered as.")
    sim_time: float | None = None
    steps: int = 0
    rate_hz: float | None = None
    stuck: bool = Field(
        False,
        description="The twin should run but finished no frame for 10 s (or 5 frame periods).",
    )
    last_step_age_s: float | None = Field(None, description="Seconds since the last frame ended.")
    robot: dict[str, float] | None = None
    people: list[dict[str, float]] = Field(default_factory=list)
    robot_error_rms_m: float | None = Field(
        None, description="RMS distance of the located robot from the twin's truth, metres."
    )
    cameras: dict[str, int] = Field(default_factory=dict)


# Frames per second of the twin's cameras: below 0.5 Hz a frame simulates seconds of motion
# (the tracker loses what it follows), above 30 Hz the frames outrun the renderer.
MIN_RATE_HZ, MAX_RATE_HZ = 0.5, 30.0


class TwinRate(Schema):
    rate_hz: float = Field(
        ge=MIN_RATE_HZ,
        le=MAX_RATE_HZ,
        allow_inf_nan=False,
        description=f"Frames per second, {MIN_RATE_HZ:g} to {MAX_RATE_HZ:g}; takes effect at once.",
    )


class Scenario(ReadSchema):
    name: str
    description: str


# The longest calibration drive a run may ask for (minutes): its programme grows with it.
MAX_DRIVE_MINUTES = MAX_DRIVE_S / 60.0


class NetworkOptions(Schema):
    seed: int = Field(0, ge=0, le=2**31 - 1)
    target: Literal["marker"] = "marker"
    stops: int = Field(
        32, ge=6, le=200, description="Stops planned per 5 minutes of the robot's drive."
    )
    minutes: float = Field(
        5.0,
        gt=0,
        le=MAX_DRIVE_MINUTES,
        allow_inf_nan=False,
        description="The longest the calibration drive may last (simulated minutes); its "
        "planned stops scale with it.",
    )
    study: bool = Field(
        True, description="Also report the accuracy against drive length and pixel noise."
    )


class NetworkRunCreate(Schema):
    """Calibrate every twin camera by driving the robot's marker over the floor."""

    kind: Literal["network"]
    options: NetworkOptions = Field(default_factory=NetworkOptions)
