"""The registry's tables. Matrices are stored as nested JSON lists (row-major), small by design;
uploaded images go to a size-capped blob table."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import (
    JSON,
    Boolean,
    DateTime,
    Float,
    ForeignKey,
    Integer,
    LargeBinary,
    String,
    Text,
    UniqueConstraint,
)
from sqlalchemy.orm import Mapped, mapped_column, relationship

from server.db.base import Base, Leased, Timestamped

# Status values of a calibration run.
RUN_QUEUED = "queued"
RUN_RUNNING = "running"
RUN_SUCCEEDED = "succeeded"
RUN_FAILED = "failed"
RUN_INTERRUPTED = "interrupted"
RUN_STATUSES = (RUN_QUEUED, RUN_RUNNING, RUN_SUCCEEDED, RUN_FAILED, RUN_INTERRUPTED)


class Space(Timestamped, Base):
    """A home (or a lab) holding rooms and devices."""

    __tablename__ = "spaces"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(200))
    description: Mapped[str] = mapped_column(Text, default="")


class Room(Timestamped, Base):
    """A room of a space with its floor polygon in world metres (z = 0 plane)."""

    __tablename__ = "rooms"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    space_id: Mapped[int] = mapped_column(ForeignKey("spaces.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(String(200))
    polygon: Mapped[list[list[float]]] = mapped_column(JSON)


class Camera(Timestamped, Base):
    """A camera: image size, intrinsics K (3x3), OpenCV distortion (5), pose T_world_camera."""

    __tablename__ = "cameras"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    space_id: Mapped[int | None] = mapped_column(
        ForeignKey("spaces.id", ondelete="SET NULL"), index=True
    )
    name: Mapped[str] = mapped_column(String(200))
    width: Mapped[int] = mapped_column(Integer)
    height: Mapped[int] = mapped_column(Integer)
    K: Mapped[list[list[float]] | None] = mapped_column(JSON)
    dist: Mapped[list[float] | None] = mapped_column(JSON)
    T_world_camera: Mapped[list[list[float]] | None] = mapped_column(JSON)
    status: Mapped[str] = mapped_column(String(20), default="uncalibrated")
    calibration_run_id: Mapped[int | None] = mapped_column(
        ForeignKey("calibration_runs.id", ondelete="SET NULL", use_alter=True)
    )
    # Boxes of a detector scored below this are dropped at ingest (migration 0009).
    score_threshold: Mapped[float] = mapped_column(Float, default=0.5, server_default="0.5")


class Projector(Timestamped, Base):
    """A projector modelled as an inverse camera: image size, K, distortion, pose."""

    __tablename__ = "projectors"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    space_id: Mapped[int | None] = mapped_column(
        ForeignKey("spaces.id", ondelete="SET NULL"), index=True
    )
    name: Mapped[str] = mapped_column(String(200))
    width: Mapped[int] = mapped_column(Integer)
    height: Mapped[int] = mapped_column(Integer)
    K: Mapped[list[list[float]] | None] = mapped_column(JSON)
    dist: Mapped[list[float] | None] = mapped_column(JSON)
    T_world_projector: Mapped[list[list[float]] | None] = mapped_column(JSON)


class Robot(Timestamped, Base):
    """A mobile manipulator: kinematic model, onboard and hand cameras, hand-eye transform."""

    __tablename__ = "robots"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    space_id: Mapped[int | None] = mapped_column(
        ForeignKey("spaces.id", ondelete="SET NULL"), index=True
    )
    name: Mapped[str] = mapped_column(String(200))
    kinematic_model: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    onboard_camera_id: Mapped[int | None] = mapped_column(
        ForeignKey("cameras.id", ondelete="SET NULL")
    )
    hand_camera_id: Mapped[int | None] = mapped_column(
        ForeignKey("cameras.id", ondelete="SET NULL")
    )
    T_hand_camera: Mapped[list[list[float]] | None] = mapped_column(JSON)


class Landmark(Timestamped, Base):
    """A printed landmark (e.g. a QR code): kind, payload, physical size, world pose if known."""

    __tablename__ = "landmarks"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    space_id: Mapped[int | None] = mapped_column(
        ForeignKey("spaces.id", ondelete="SET NULL"), index=True
    )
    kind: Mapped[str] = mapped_column(String(40))
    payload: Mapped[str] = mapped_column(Text)
    size_m: Mapped[float] = mapped_column(Float)
    T_world_landmark: Mapped[list[list[float]] | None] = mapped_column(JSON)


class CalibrationRun(Leased, Timestamped, Base):
    """One calibration job: its inputs, status, result or error, and timings."""

    __tablename__ = "calibration_runs"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    kind: Mapped[str] = mapped_column(String(40))
    source: Mapped[str] = mapped_column(String(40))  # "correspondences" or "images"
    status: Mapped[str] = mapped_column(String(20), default=RUN_QUEUED, index=True)
    camera_id: Mapped[int | None] = mapped_column(
        ForeignKey("cameras.id", ondelete="SET NULL"), index=True
    )
    # A hand-eye run's arm (migration 0008).
    arm_id: Mapped[int | None] = mapped_column(
        ForeignKey("arms.id", ondelete="SET NULL"), index=True
    )
    inputs: Mapped[dict[str, Any]] = mapped_column(JSON)
    options: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    result: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    error: Mapped[str | None] = mapped_column(Text)
    started_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    finished_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    # How far the current attempt has come (its claim: the Leased columns).
    progress_stage: Mapped[str | None] = mapped_column(String(80))
    progress_fraction: Mapped[float | None] = mapped_column(Float)

    files: Mapped[list[CalibrationRunFile]] = relationship(
        back_populates="run", cascade="all, delete-orphan", passive_deletes=True
    )


class CalibrationRunFile(Timestamped, Base):
    """An image uploaded for a run, kept as a blob (capped by the upload size limit)."""

    __tablename__ = "calibration_run_files"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    run_id: Mapped[int] = mapped_column(
        ForeignKey("calibration_runs.id", ondelete="CASCADE"), index=True
    )
    position: Mapped[int] = mapped_column(Integer)
    filename: Mapped[str] = mapped_column(String(255))
    content_type: Mapped[str] = mapped_column(String(100))
    size: Mapped[int] = mapped_column(Integer)
    data: Mapped[bytes] = mapped_column(LargeBinary)

    run: Mapped[CalibrationRun] = relationship(back_populates="files")


class CameraCalibration(Timestamped, Base):
    """A calibration applied to a camera; the rows of one camera are its history."""

    __tablename__ = "camera_calibrations"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    camera_id: Mapped[int] = mapped_column(ForeignKey("cameras.id", ondelete="CASCADE"), index=True)
    calibration_run_id: Mapped[int | None] = mapped_column(
        ForeignKey("calibration_runs.id", ondelete="SET NULL")
    )
    K: Mapped[list[list[float]]] = mapped_column(JSON)
    dist: Mapped[list[float]] = mapped_column(JSON)
    rms: Mapped[float | None] = mapped_column(Float)
    image_width: Mapped[int] = mapped_column(Integer)
    image_height: Mapped[int] = mapped_column(Integer)


class ApiToken(Timestamped, Base):
    """A bearer token, stored as its SHA-256 hex digest; the token itself is shown once.

    kind "api": a token for scripts and camera nodes (an ingest token may name the cameras it
    speaks for); kind "session": a browser's sign-in, made from the token it signed in with
    (`parent_id`, None for the configured admin token), ending at `expires_at` (Unix s)."""

    __tablename__ = "api_tokens"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(200))
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    scopes: Mapped[list[str]] = mapped_column(JSON)
    revoked: Mapped[bool] = mapped_column(Boolean, default=False)
    kind: Mapped[str] = mapped_column(String(20), default="api", server_default="api")
    camera_ids: Mapped[list[int] | None] = mapped_column(JSON, nullable=True)
    expires_at: Mapped[float | None] = mapped_column(Float, nullable=True)
    parent_id: Mapped[int | None] = mapped_column(
        ForeignKey("api_tokens.id", ondelete="CASCADE"), nullable=True, index=True
    )


# Kinds of a located target and of a detection: one vocabulary (spec 08).
TARGET_KINDS = ("robot", "person", "unknown")
# Life cycle states of a target (core.localization.tracking.TrackState); live = the first two.
TARGET_STATES = ("confirmed", "coasting", "ended")


class Target(Timestamped, Base):
    """A body the space's tracker follows on the floor (the robot, a person, or of unknown
    kind): its label, life cycle state, first and last update times (Unix seconds) and its
    latest position."""

    __tablename__ = "targets"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    space_id: Mapped[int | None] = mapped_column(
        ForeignKey("spaces.id", ondelete="SET NULL"), index=True
    )
    label: Mapped[str] = mapped_column(String(200), unique=True)
    kind: Mapped[str] = mapped_column(String(20))
    state: Mapped[str] = mapped_column(String(20), default="confirmed", index=True)
    track_id: Mapped[int | None] = mapped_column(Integer)
    first_seen: Mapped[float | None] = mapped_column(Float)
    last_seen: Mapped[float | None] = mapped_column(Float, index=True)
    t: Mapped[float | None] = mapped_column(Float)
    xy: Mapped[list[float] | None] = mapped_column(JSON)
    cov: Mapped[list[list[float]] | None] = mapped_column(JSON)


class TrackPoint(Timestamped, Base):
    """One tracked position of a target: time (Unix seconds, the observation's own), floor
    (x, y) metres and its 2x2 covariance m^2."""

    __tablename__ = "track_points"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    target_id: Mapped[int] = mapped_column(ForeignKey("targets.id", ondelete="CASCADE"), index=True)
    t: Mapped[float] = mapped_column(Float, index=True)
    x: Mapped[float] = mapped_column(Float)
    y: Mapped[float] = mapped_column(Float)
    cov: Mapped[list[list[float]]] = mapped_column(JSON)


class Detection(Timestamped, Base):
    """One detection a camera sent (spec 08): camera, capture time (Unix seconds), distorted
    pixel (u, v) with its covariance (cxx, cxy, cyy) px^2, kind, the height (m) of the point it
    measures, and the label when the sender knew the target. A detector's box (migration 0009):
    `box` [x0, y0, x1, y1] distorted px, its `score` (0-1) and the sides `cut` by the image's
    edge or a mask; (u, v) is then the box's foot point (core.localization.box_foot), not
    tracked when the bottom is cut. Its `appearance` (migration 0012): the box's descriptor
    (core.localization.appearance), when the sender gave one."""

    __tablename__ = "detections"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    space_id: Mapped[int | None] = mapped_column(
        ForeignKey("spaces.id", ondelete="CASCADE"), index=True
    )
    camera_id: Mapped[int] = mapped_column(ForeignKey("cameras.id", ondelete="CASCADE"))
    t: Mapped[float] = mapped_column(Float, index=True)
    u: Mapped[float] = mapped_column(Float)
    v: Mapped[float] = mapped_column(Float)
    cxx: Mapped[float] = mapped_column(Float)
    cxy: Mapped[float] = mapped_column(Float)
    cyy: Mapped[float] = mapped_column(Float)
    kind: Mapped[str] = mapped_column(String(20))
    height: Mapped[float] = mapped_column(Float)
    label: Mapped[str | None] = mapped_column(String(200))
    box: Mapped[list[float] | None] = mapped_column(JSON(none_as_null=True))
    score: Mapped[float | None] = mapped_column(Float)
    cut: Mapped[list[str] | None] = mapped_column(JSON(none_as_null=True))
    appearance: Mapped[list[float] | None] = mapped_column(JSON(none_as_null=True))


class SemanticObject(Timestamped, Base):
    """An object of a space's semantic map (spec 04): one row per object mark read (`mark_id`,
    the id its payload carries), with class, name, room, the fused world pose T_world_mark and
    its 6x6 covariance (rotation perturbation rad, position m), last seen (Unix s), how many
    reads were fused and the payload text last read."""

    __tablename__ = "semantic_objects"
    __table_args__ = (UniqueConstraint("space_id", "mark_id"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    space_id: Mapped[int] = mapped_column(ForeignKey("spaces.id", ondelete="CASCADE"), index=True)
    mark_id: Mapped[int] = mapped_column(Integer)
    object_class: Mapped[str] = mapped_column(String(200))
    name: Mapped[str] = mapped_column(String(200))
    room: Mapped[str] = mapped_column(String(200))
    T_world_mark: Mapped[list[list[float]]] = mapped_column(JSON)
    cov: Mapped[list[list[float]]] = mapped_column(JSON)
    last_seen: Mapped[float] = mapped_column(Float)
    reads: Mapped[int] = mapped_column(Integer)
    confidence: Mapped[float] = mapped_column(Float)
    payload: Mapped[str] = mapped_column(Text)


class NavigationPlace(Timestamped, Base):
    """A place of a space's navigation map: a signpost read (`mark_id`), its name, room, world
    pose (x, y, z, qx, qy, qz, qw) from its payload, neighbour mark ids, last seen (Unix s) and
    the payload text."""

    __tablename__ = "navigation_places"
    __table_args__ = (UniqueConstraint("space_id", "mark_id"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    space_id: Mapped[int] = mapped_column(ForeignKey("spaces.id", ondelete="CASCADE"), index=True)
    mark_id: Mapped[int] = mapped_column(Integer)
    name: Mapped[str] = mapped_column(String(200))
    room: Mapped[str] = mapped_column(String(200))
    pose: Mapped[list[float]] = mapped_column(JSON)
    neighbours: Mapped[list[int]] = mapped_column(JSON)
    last_seen: Mapped[float] = mapped_column(Float)
    reads: Mapped[int] = mapped_column(Integer)
    payload: Mapped[str] = mapped_column(Text)


class NavigationEdge(Timestamped, Base):
    """An edge of a space's navigation map between two places (their mark ids, from < to):
    its length (m) and what made it ("neighbour": a payload's neighbour field; "room": the two
    share a room)."""

    __tablename__ = "navigation_edges"
    __table_args__ = (UniqueConstraint("space_id", "from_mark", "to_mark"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    space_id: Mapped[int] = mapped_column(ForeignKey("spaces.id", ondelete="CASCADE"), index=True)
    from_mark: Mapped[int] = mapped_column(Integer)
    to_mark: Mapped[int] = mapped_column(Integer)
    length_m: Mapped[float] = mapped_column(Float)
    via: Mapped[str] = mapped_column(String(20))


# Status values of a path's follow task (server.services.path_following).
FOLLOW_STATUSES = ("idle", "running", "succeeded", "failed", "interrupted")


class PlannedPath(Leased, Timestamped, Base):
    """A path planned on a space's floor plan (spec 03): start and goal (x, y) m, the planned
    poly-line `points` and its `length_m`, the planning inputs (robot radius, grid resolution,
    which floor plan), and when a projector draws it: the projector model used and the joint
    trajectory (`trajectory`: t s, q rad, spot m). The follow task on the twin keeps its status,
    law, progress, metrics and tracking-error series (t s, error m) on the row, with its lease
    (Leased)."""

    __tablename__ = "paths"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    space_id: Mapped[int] = mapped_column(ForeignKey("spaces.id", ondelete="CASCADE"), index=True)
    projector_id: Mapped[int | None] = mapped_column(
        ForeignKey("projectors.id", ondelete="SET NULL")
    )
    start: Mapped[list[float]] = mapped_column(JSON)
    goal: Mapped[list[float]] = mapped_column(JSON)
    points: Mapped[list[list[float]]] = mapped_column(JSON)
    length_m: Mapped[float] = mapped_column(Float)
    robot_radius_m: Mapped[float] = mapped_column(Float)
    resolution_m: Mapped[float] = mapped_column(Float)
    floor_plan: Mapped[str] = mapped_column(String(200))
    spot_speed_mps: Mapped[float | None] = mapped_column(Float)
    projector_model: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    trajectory: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    follow_status: Mapped[str] = mapped_column(String(20), default="idle")
    follow_law: Mapped[str | None] = mapped_column(String(40))
    follow_seed: Mapped[int | None] = mapped_column(Integer)
    follow_progress: Mapped[float | None] = mapped_column(Float)
    follow_result: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    follow_series: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    follow_error: Mapped[str | None] = mapped_column(Text)
    follow_started_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    follow_finished_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))


class Arm(Timestamped, Base):
    """An arm mounted on a robot (spec 05): its standard Denavit-Hartenberg parameters `dh`
    ({a, d, alpha, offset}: six values each, metres and radians), joint `limits` (6 x [lower,
    upper] rad), `tool` T_flange_ee and mount `T_robot_arm` (4x4, metres), a `home`
    configuration (rad), its eye-in-hand camera and the hand-eye transform T_ee_camera applied
    last (by `hand_eye_run_id`, or typed in: no run)."""

    __tablename__ = "arms"
    __table_args__ = (UniqueConstraint("robot_id", "name"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    robot_id: Mapped[int] = mapped_column(ForeignKey("robots.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(String(200))
    dh: Mapped[dict[str, list[float]]] = mapped_column(JSON)
    limits: Mapped[list[list[float]]] = mapped_column(JSON)
    tool: Mapped[list[list[float]]] = mapped_column(JSON)
    home: Mapped[list[float]] = mapped_column(JSON)
    T_robot_arm: Mapped[list[list[float]]] = mapped_column(JSON)
    camera_id: Mapped[int | None] = mapped_column(ForeignKey("cameras.id", ondelete="SET NULL"))
    T_ee_camera: Mapped[list[list[float]] | None] = mapped_column(JSON)
    hand_eye_run_id: Mapped[int | None] = mapped_column(
        ForeignKey("calibration_runs.id", ondelete="SET NULL", use_alter=True)
    )


class HandEyeCalibration(Timestamped, Base):
    """A hand-eye calibration applied to an arm; the rows of one arm are its history: the
    transform T_ee_camera, its rotation (deg) and translation (m) standard deviations, the
    refinement's reprojection RMS (px, None without one) and the method."""

    __tablename__ = "hand_eye_calibrations"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    arm_id: Mapped[int] = mapped_column(ForeignKey("arms.id", ondelete="CASCADE"), index=True)
    calibration_run_id: Mapped[int | None] = mapped_column(
        ForeignKey("calibration_runs.id", ondelete="SET NULL")
    )
    T_ee_camera: Mapped[list[list[float]]] = mapped_column(JSON)
    rotation_std_deg: Mapped[float] = mapped_column(Float)
    translation_std_m: Mapped[float] = mapped_column(Float)
    rms_px: Mapped[float | None] = mapped_column(Float)
    method: Mapped[str] = mapped_column(String(40))


# Status values of a task (server.services.manipulation).
TASK_STATUSES = ("queued", "running", "succeeded", "failed", "interrupted")


class Task(Leased, Timestamped, Base):
    """A robot task run on the twin (kind "fetch": grasp episodes with an arm): its inputs,
    status, current phase and progress (0-1), result (filled episode by episode) or error, and
    the lease of the process running it (Leased)."""

    __tablename__ = "tasks"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    kind: Mapped[str] = mapped_column(String(40))
    status: Mapped[str] = mapped_column(String(20), default="queued", index=True)
    arm_id: Mapped[int | None] = mapped_column(
        ForeignKey("arms.id", ondelete="SET NULL"), index=True
    )
    inputs: Mapped[dict[str, Any]] = mapped_column(JSON)
    phase: Mapped[str | None] = mapped_column(String(80))
    progress: Mapped[float | None] = mapped_column(Float)
    result: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    error: Mapped[str | None] = mapped_column(Text)
    started_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    finished_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))


class ProjectorCalibration(Timestamped, Base):
    """A calibration applied to a projector (spec 03 section 2); the rows of one projector are
    its history: the mount pose T_world_projector (the pan-tilt base), the tilt joint's zero
    offset (rad), the floor RMS (m) and the number of spots it used."""

    __tablename__ = "projector_calibrations"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    projector_id: Mapped[int] = mapped_column(
        ForeignKey("projectors.id", ondelete="CASCADE"), index=True
    )
    calibration_run_id: Mapped[int | None] = mapped_column(
        ForeignKey("calibration_runs.id", ondelete="SET NULL")
    )
    T_world_projector: Mapped[list[list[float]]] = mapped_column(JSON)
    tilt_offset: Mapped[float] = mapped_column(Float)
    rms_m: Mapped[float] = mapped_column(Float)
    spots: Mapped[int] = mapped_column(Integer)


class Zone(Timestamped, Base):
    """A zone of a space's floor plan (spec 09): a polygon in world metres, its name and the
    name's slug (unique in the space, the zone's MQTT topic), the inertia (s) before a person
    counts as in or out, and the loitering time (s; 0: none)."""

    __tablename__ = "zones"
    __table_args__ = (UniqueConstraint("space_id", "slug"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    space_id: Mapped[int] = mapped_column(ForeignKey("spaces.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(String(200))
    slug: Mapped[str] = mapped_column(String(200))
    polygon: Mapped[list[list[float]]] = mapped_column(JSON)
    inertia_s: Mapped[float] = mapped_column(Float, default=1.0)
    loiter_s: Mapped[float] = mapped_column(Float, default=0.0)
