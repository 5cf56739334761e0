"""The scene schema of the digital twin: a home described in YAML or JSON, validated strictly.

Units are SI (metres, radians, seconds); the world frame is right-handed with Z up and the floor
at Z = 0; colours are written (r, g, b) with 0..255 integers; quaternions are (x, y, z, w).
A pose is given either as a position and a look-at point (the camera's optical axis, OpenCV
frame: x right, y down, z forward, image "up" towards world +Z) or as a position and a quaternion
`quaternion_xyzw` rotating body coordinates into the world frame (R_world_body).

Loading is `load_scene(text_or_dict)` (YAML or JSON text, or an already parsed mapping) and
`default_scene()` (the home that ships with the package). Core performs no file I/O of its own:
the caller reads a file and passes its text. Every validation failure is raised as
core.errors.InvalidInput naming the field path (e.g. `cameras.2.intrinsics.fx`) and the reason.
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Mapping
from functools import lru_cache
from importlib import resources
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, model_validator

from core.errors import InvalidInput


def _to_tuple(v: Any) -> Any:
    # YAML and JSON give sequences as lists; the strict schema wants tuples for fixed-size
    # vectors, so convert the container only (the elements are still validated strictly).
    return tuple(v) if isinstance(v, list) else v


Vec2 = Annotated[tuple[float, float], BeforeValidator(_to_tuple)]
Vec3 = Annotated[tuple[float, float, float], BeforeValidator(_to_tuple)]
Vec4 = Annotated[tuple[float, float, float, float], BeforeValidator(_to_tuple)]
Colour = Annotated[
    tuple[
        Annotated[int, Field(ge=0, le=255)],
        Annotated[int, Field(ge=0, le=255)],
        Annotated[int, Field(ge=0, le=255)],
    ],
    BeforeValidator(_to_tuple),
]
Size2 = Annotated[
    tuple[Annotated[int, Field(gt=0)], Annotated[int, Field(gt=0)]], BeforeValidator(_to_tuple)
]
Matrix3 = Annotated[tuple[Vec3, Vec3, Vec3], BeforeValidator(_to_tuple)]
Interval = Annotated[tuple[float, float], BeforeValidator(_to_tuple)]
Positive = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
NonNegative = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
Name = Annotated[str, Field(min_length=1, max_length=100)]
Size3 = Annotated[tuple[Positive, Positive, Positive], BeforeValidator(_to_tuple)]


class _Model(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)


class Pose(_Model):
    """A rigid pose in the world (or a parent) frame: position and look_at, or position and
    quaternion_xyzw (R_parent_body). Exactly one of look_at and quaternion_xyzw is given."""

    position: Vec3
    look_at: Vec3 | None = None
    quaternion_xyzw: Vec4 | None = None

    @model_validator(mode="after")
    def _one_orientation(self) -> Pose:
        if (self.look_at is None) == (self.quaternion_xyzw is None):
            raise ValueError("give exactly one of look_at and quaternion_xyzw")
        if self.look_at is not None:
            d = [a - b for a, b in zip(self.look_at, self.position, strict=True)]
            if math.hypot(*d) < 1e-6:
                raise ValueError("look_at must differ from position")
            if math.hypot(d[0], d[1]) < 1e-6 * math.hypot(*d):
                raise ValueError(
                    "look_at straight up or down leaves the image rotation undefined; "
                    "give a quaternion_xyzw instead"
                )
        if self.quaternion_xyzw is not None and abs(math.hypot(*self.quaternion_xyzw) - 1) > 1e-3:
            raise ValueError("quaternion_xyzw must have unit norm (within 1e-3)")
        return self


class Tiles(_Model):
    """A tiled floor: square tiles of `size` metres in two alternating colours with grout lines,
    each tile's brightness jittered by a seeded random amount so cameras see structure."""

    size: Positive = 0.5
    colour_a: Colour = (205, 195, 175)
    colour_b: Colour = (160, 150, 130)
    grout_colour: Colour = (110, 105, 95)
    grout_width: NonNegative = 0.01
    jitter: Annotated[float, Field(ge=0.0, le=0.5)] = 0.06
    seed: Annotated[int, Field(ge=0)] = 0
    pixels_per_metre: Annotated[float, Field(ge=16.0, le=1000.0)] = 160.0


class Room(_Model):
    """A named room: a simple polygon (counter-clockwise or not) on the floor, (x, y) metres."""

    name: Name
    polygon: Annotated[list[Vec2], Field(min_length=3)]
    floor: Tiles | None = None


class Door(_Model):
    """An opening in a wall: starts `offset` metres along the wall from its start point."""

    offset: NonNegative
    width: Positive
    height: Positive


class Wall(_Model):
    """A straight wall from `start` to `end` (x, y metres), `height` and `thickness` metres."""

    name: Name | None = None
    start: Vec2
    end: Vec2
    height: Positive
    thickness: Positive = 0.1
    colour: Colour = (225, 222, 210)
    doors: list[Door] = Field(default_factory=list)

    @model_validator(mode="after")
    def _doors_fit(self) -> Wall:
        length = math.dist(self.start, self.end)
        if length < 1e-3:
            raise ValueError("start and end must differ")
        spans = sorted((d.offset, d.offset + d.width) for d in self.doors)
        for (_, a1), (b0, _) in itertools.pairwise(spans):
            if b0 < a1:
                raise ValueError(f"doors overlap at {b0:.3f} m along the wall")
        for d in self.doors:
            if d.offset + d.width > length + 1e-9:
                raise ValueError(f"a door ends beyond the wall's length {length:.3f} m")
            if d.height > self.height:
                raise ValueError("a door is taller than its wall")
        return self


class Furniture(_Model):
    """A named box standing on the floor: centre (x, y), size (length x, width y, height z)
    in its own frame, turned by `yaw` radians about world Z."""

    name: Name
    centre: Vec2
    size: Size3
    yaw: float = 0.0
    colour: Colour = (150, 150, 150)


class Intrinsics(_Model):
    """Pinhole intrinsics in pixels: either fx, fy, cx, cy (skew 0) or a full K."""

    fx: Positive | None = None
    fy: Positive | None = None
    cx: float | None = None
    cy: float | None = None
    K: Matrix3 | None = None

    @model_validator(mode="after")
    def _one_form(self) -> Intrinsics:
        parts = (self.fx, self.fy, self.cx, self.cy)
        if self.K is not None:
            if any(p is not None for p in parts):
                raise ValueError("give either K or fx, fy, cx, cy, not both")
            K = self.K
            if K[1][0] != 0 or K[2][0] != 0 or K[2][1] != 0 or K[2][2] != 1:
                raise ValueError("K must be upper triangular with K[2][2] = 1")
            if K[0][0] <= 0 or K[1][1] <= 0:
                raise ValueError("K must have positive focal lengths")
        elif any(p is None for p in parts):
            raise ValueError("give K or all of fx, fy, cx, cy")
        return self

    def matrix(self) -> tuple[Vec3, Vec3, Vec3]:
        """Return K as three rows."""
        if self.K is not None:
            return self.K
        assert self.fx is not None and self.fy is not None
        assert self.cx is not None and self.cy is not None
        return ((self.fx, 0.0, self.cx), (0.0, self.fy, self.cy), (0.0, 0.0, 1.0))


class Distortion(_Model):
    """OpenCV lens distortion: radial k1, k2, k3 and tangential p1, p2 (dimensionless)."""

    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    p1: float = 0.0
    p2: float = 0.0

    def opencv(self) -> tuple[float, float, float, float, float]:
        """Return the coefficients in OpenCV's order (k1, k2, p1, p2, k3)."""
        return (self.k1, self.k2, self.p1, self.p2, self.k3)


class CeilingCamera(_Model):
    """A fixed camera: resolution (width, height) pixels, intrinsics, distortion, pose of the
    camera frame (OpenCV convention) in the world, frame rate in Hz."""

    name: Name
    resolution: Size2
    intrinsics: Intrinsics
    distortion: Distortion = Distortion()
    pose: Pose
    frame_rate: Positive = 15.0


class Projector(_Model):
    """The ceiling laser projector: base pose and its two joints' limits (parameters only)."""

    name: Name
    pose: Pose
    pan_limits: Interval = (-math.pi, math.pi)
    tilt_limits: Interval = (0.0, 1.4)
    max_rate: Positive = 3.0

    @model_validator(mode="after")
    def _ordered(self) -> Projector:
        for label, (lo, hi) in (("pan_limits", self.pan_limits), ("tilt_limits", self.tilt_limits)):
            if not lo < hi:
                raise ValueError(f"{label} must be (lower, upper) with lower < upper")
        return self


class TopMarker(_Model):
    """A flat coloured disc on top of the robot, facing up: centre at (offset, height) in the
    robot frame (x forward, y left, z up, origin on the floor under the base centre)."""

    colour: Colour = (220, 20, 30)
    radius: Positive = 0.05
    height: Positive = 0.36
    offset: Vec2 = (0.0, 0.0)


class Board(_Model):
    """A chessboard mounted on the robot. `inner_corners` = (columns, rows) of inner corners;
    its columns run along the robot's y axis. Before tilting the board lies flat, face up,
    centred at (offset, mounting_height) in the robot frame; `tilt` (radians) turns it about the
    robot's y axis so that its face looks forward and up. `margin` is the white border in
    squares. `enabled` lets a scene carry the board without mounting it."""

    enabled: bool = True
    inner_corners: Size2 = (6, 4)
    square_size: Positive = 0.08
    margin: Annotated[float, Field(ge=0.5, le=3.0)] = 1.0
    tilt: Annotated[float, Field(ge=0.0, le=1.4)] = 0.5
    mounting_height: Positive = 0.5
    offset: Vec2 = (0.0, 0.0)


class CameraMount(_Model):
    """An onboard camera (parameters only): pose in the robot frame and its optics."""

    pose: Pose
    resolution: Size2 = (640, 480)
    intrinsics: Intrinsics
    distortion: Distortion = Distortion()


class HeadCamera(_Model):
    """The robot's head camera on a pan-tilt unit (parameters only): the joints' centre at
    `position` (x, y, z metres in the robot frame); at pan = tilt = 0 the optical axis looks
    along the robot's +x with image up towards +z; pan turns about the robot's z (positive to
    the left), then tilt about the panned y axis (positive down); limits in radians, rate in
    rad/s; the camera's resolution (width, height), intrinsics and distortion."""

    position: Vec3 = (0.1, 0.0, 1.1)
    pan_limits: Interval = (-2.8, 2.8)
    tilt_limits: Interval = (-1.0, 1.0)
    max_rate: Positive = 2.0
    resolution: Size2 = (640, 480)
    intrinsics: Intrinsics
    distortion: Distortion = Distortion()

    @model_validator(mode="after")
    def _ordered(self) -> HeadCamera:
        for label, (lo, hi) in (("pan_limits", self.pan_limits), ("tilt_limits", self.tilt_limits)):
            if not lo < hi:
                raise ValueError(f"{label} must be (lower, upper) with lower < upper")
        return self


class MotionLimits(_Model):
    """Limits of the unicycle base: |v| <= max_speed (m/s), |omega| <= max_turn_rate (rad/s),
    |dv/dt| <= max_acceleration (m/s^2), |domega/dt| <= max_angular_acceleration (rad/s^2)."""

    max_speed: Positive = 0.5
    max_turn_rate: Positive = 1.5
    max_acceleration: Positive = 0.8
    max_angular_acceleration: Positive = 3.0


class SlipNoise(_Model):
    """Wheel-slip noise, a random walk per metre or radian travelled (Thrun et al., Probabilistic
    Robotics, sec. 5.4): over a drive of d metres and turn of a radians the true motion departs
    from the wheels' by distance sigma distance_per_sqrt_m sqrt(d), lateral sigma
    lateral_per_sqrt_m sqrt(d) and heading sigma sqrt(heading_per_sqrt_m^2 d +
    heading_per_sqrt_rad^2 |a|)."""

    distance_per_sqrt_m: NonNegative = 0.01
    lateral_per_sqrt_m: NonNegative = 0.005
    heading_per_sqrt_m: NonNegative = 0.01
    heading_per_sqrt_rad: NonNegative = 0.01


class Robot(_Model):
    """The mobile robot: a cylinder base (radius, height metres), limits, noise, its top marker,
    an optional second marker on a thin mast (its disc at the mast's top: the image of a marker
    above another gives a ceiling camera its tilt at every stop of a calibration drive; a
    different colour tells the two apart), an optional chessboard, an optional onboard (floor)
    camera, an optional head camera on a pan-tilt unit, and its start pose (x, y, yaw).

    The mast is either always up (`mast_marker`) or telescopic (`calibration_mast`): stowed in
    the base in normal use, where its rod would cross the top marker and join walkers' blobs
    to the robot's, and raised for the network calibration drive only (`raise_mast`)."""

    name: Name
    base_radius: Positive = 0.2
    base_height: Positive = 0.35
    colour: Colour = (90, 95, 100)
    top_colour: Colour = (50, 52, 55)
    limits: MotionLimits = MotionLimits()
    slip: SlipNoise = SlipNoise()
    marker: TopMarker | None = TopMarker()
    mast_marker: TopMarker | None = None
    calibration_mast: TopMarker | None = None
    board: Board | None = None
    onboard_camera: CameraMount | None = None
    head_camera: HeadCamera | None = None
    start: Vec3 = (1.0, 1.0, 0.0)
    patrol: list[Vec2] = Field(default_factory=list)

    @model_validator(mode="after")
    def _one_mast(self) -> Robot:
        if self.mast_marker is not None and self.calibration_mast is not None:
            raise ValueError("a robot has one mast: set mast_marker or calibration_mast, not both")
        return self


class Landmark(_Model):
    """A printed landmark (parameters only here): a square of side `size` metres whose face
    normal is the pose's body +z axis, with its payload text."""

    name: Name
    kind: Literal["object_mark", "signpost"]
    pose: Pose
    size: Positive
    payload: str = ""


class Walker(_Model):
    """A scripted person: walks the polyline of `waypoints` at `speed` m/s, back and forth
    (`loop` false) or around (`loop` true), standing still for `pauses[i]` seconds each time
    it reaches waypoint i (none when `pauses` is empty); body a vertical cylinder of radius
    and height."""

    name: Name
    waypoints: Annotated[list[Vec2], Field(min_length=2)]
    speed: Positive = 0.8
    loop: bool = False
    pauses: list[Annotated[float, Field(ge=0.0, le=3600.0, allow_inf_nan=False)]] = Field(
        default_factory=list
    )
    radius: Positive = 0.2
    height: Positive = 1.7
    colour: Colour = (40, 110, 60)

    @model_validator(mode="after")
    def _pause_per_waypoint(self) -> Walker:
        if self.pauses and len(self.pauses) != len(self.waypoints):
            raise ValueError(
                f"pauses must hold one value per waypoint ({len(self.waypoints)}), "
                f"got {len(self.pauses)}"
            )
        return self


class Scene(_Model):
    """A whole simulated space: floor plan, cameras, projector, robot, landmarks and people."""

    name: Name
    ceiling_height: Positive
    floor: Tiles = Tiles()
    background: Colour = (30, 30, 30)
    ceiling_colour: Colour = (240, 238, 232)
    rooms: Annotated[list[Room], Field(min_length=1)]
    walls: list[Wall] = Field(default_factory=list)
    furniture: list[Furniture] = Field(default_factory=list)
    cameras: list[CeilingCamera] = Field(default_factory=list)
    projector: Projector | None = None
    robot: Robot | None = None
    landmarks: list[Landmark] = Field(default_factory=list)
    people: list[Walker] = Field(default_factory=list)

    @model_validator(mode="after")
    def _unique_names(self) -> Scene:
        for label, items in (
            ("cameras", self.cameras),
            ("rooms", self.rooms),
            ("furniture", self.furniture),
            ("people", self.people),
            ("landmarks", self.landmarks),
        ):
            names = [i.name for i in items]
            dup = sorted({n for n in names if names.count(n) > 1})
            if dup:
                raise ValueError(f"{label} names must be unique; repeated: {', '.join(dup)}")
        for w in self.walls:
            if w.height > self.ceiling_height + 1e-9:
                raise ValueError(f"wall {w.name or w.start} is taller than the ceiling")
        return self

    def camera(self, name: str) -> CeilingCamera:
        """Return the ceiling camera called `name`; raise InvalidInput listing the names."""
        for c in self.cameras:
            if c.name == name:
                return c
        known = ", ".join(c.name for c in self.cameras) or "none"
        raise InvalidInput(f"no camera named {name!r} in scene {self.name!r}; cameras: {known}")


def _format_errors(exc: ValidationError) -> str:
    lines = []
    for err in exc.errors(include_url=False):
        # The BeforeValidator and union branches add type names to the location; keep fields.
        loc = ".".join(str(p) for p in err["loc"]) or "(scene)"
        lines.append(f"{loc}: {err['msg']}")
    return "invalid scene: " + "; ".join(lines)


def load_scene(source: str | Mapping[str, Any]) -> Scene:
    """Return the validated Scene from YAML or JSON text, or from an already parsed mapping.

    Raises InvalidInput whose message names each offending field path and the reason, e.g.
    "invalid scene: cameras.0.intrinsics.fx: Input should be greater than 0".
    """
    if isinstance(source, str):
        try:
            data = yaml.safe_load(source)  # YAML 1.1 is a superset of JSON for our inputs
        except yaml.YAMLError as exc:
            raise InvalidInput(f"scene text is neither valid YAML nor JSON: {exc}") from None
    elif isinstance(source, Mapping):
        data = dict(source)
    else:
        raise InvalidInput(f"load_scene takes YAML/JSON text or a mapping, got {type(source)}")
    if not isinstance(data, dict):
        raise InvalidInput("a scene must be a mapping at the top level (name, rooms, ...)")
    try:
        return Scene.model_validate(data)
    except ValidationError as exc:
        raise InvalidInput(_format_errors(exc)) from None


@lru_cache(maxsize=1)
def default_scene() -> Scene:
    """Return the default home shipped with the package (core/sim/data/default_home.yaml)."""
    text = resources.files("core.sim").joinpath("data/default_home.yaml").read_text("utf-8")
    return load_scene(text)


def raise_mast(scene: Scene) -> Scene:
    """Return the scene with its robot's telescopic mast raised (its `calibration_mast` as the
    `mast_marker` the renderer draws and the drive observes); the scene itself when its robot
    has no telescopic mast."""
    robot = scene.robot
    if robot is None or robot.calibration_mast is None:
        return scene
    raised = robot.model_copy(
        update={"mast_marker": robot.calibration_mast, "calibration_mast": None}
    )
    return scene.model_copy(update={"robot": raised})


def scene_to_json(scene: Scene) -> str:
    """Return the scene as JSON text that load_scene reads back to an equal Scene."""
    return json.dumps(scene.model_dump(mode="json"), indent=2)
