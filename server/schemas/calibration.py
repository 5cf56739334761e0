"""Schemas of calibration runs: inline correspondences in, status and result out."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field, model_validator

from server.schemas.common import Finite, Id, PixelCount, ReadSchema, Schema, UtcDatetime

# Lens models of core.calibration.calibrate_camera, by the coefficients they estimate.
DistortionModel = Literal["none", "k1", "k1k2", "k1k2p1p2", "k1k2p1p2k3"]
RunStatus = Literal["queued", "running", "succeeded", "failed", "interrupted"]

Point2 = Annotated[list[Finite], Field(min_length=2, max_length=2)]
Point3 = Annotated[list[Finite], Field(min_length=3, max_length=3)]
MAX_VIEWS = 200
MAX_POINTS_PER_VIEW = 10_000

# A calibration board's square (or circle spacing) above this is a unit slip, not a board.
MAX_SQUARE_M = 1.0


def implausible_square(square_m: float) -> str | None:
    """Return why a board square of `square_m` metres is implausible, with the value meant
    (millimetres or centimetres typed as metres), or None when it is plausible."""
    if square_m <= MAX_SQUARE_M:
        return None
    meant = f"{square_m / 1000:g} ({square_m:g} mm)"
    if square_m < 100:
        meant += f" or {square_m / 100:g} ({square_m:g} cm)"
    return (
        f"a {square_m:g} m square is larger than any calibration board (at most "
        f"{MAX_SQUARE_M:g} m); the size is in metres: did you mean {meant}?"
    )


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


class SkippedPhoto(ReadSchema):
    """An uploaded photo a run did not use."""

    index: int = Field(description="Position of the image in the upload, from 0.")
    filename: str
    reason: str


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
    skipped: list[SkippedPhoto] = Field(
        default_factory=list, description="Uploaded images the run could not use, and why."
    )


class NetworkCameraErrors(ReadSchema):
    """A calibrated camera's errors against the twin's true camera (scoring)."""

    focal_pct: float = Field(description="Focal length error, percent of the truth (signed).")
    position_m: float = Field(
        description="Optical centre position error, metres, in the world (registered by the "
        "signposts when `registration` says so, else in the frame the robot's start pose "
        "defines)."
    )
    rotation_deg: float = Field(description="Orientation error (angle of R_est R_true^T), deg.")
    aligned_position_m: float | None = Field(
        None,
        description="Position error after removing the floor rigid motion (x, y, yaw) that "
        "best aligns all calibrated centres: the network's own geometry, metres.",
    )
    aligned_rotation_deg: float | None = Field(
        None, description="Orientation error after the same alignment, degrees."
    )
    start_frame_position_m: float | None = Field(
        None, description="Position error before the registration, in the start pose's frame."
    )
    start_frame_rotation_deg: float | None = Field(
        None, description="Orientation error before the registration, degrees."
    )


class NetworkCameraBound(ReadSchema):
    """The Cramer-Rao bound of the same errors (standard deviation of the focal length in
    percent; root mean square position m and orientation deg)."""

    focal_pct: float | None = None
    position_m: float | None = None
    rotation_deg: float | None = None
    aligned_position_m: float | None = None
    aligned_rotation_deg: float | None = None


class NetworkCameraResult(ReadSchema):
    name: str
    camera_id: int | None = None
    K: list[list[float]]
    dist: list[float]
    T_world_camera: list[list[float]]
    std: dict[str, Any] = Field(
        description="Standard deviations scaled by the measured residual variance: f_px (of "
        "(fx + fy) / 2, pixels), rvec_rad, t_m and `parameters` by name (fx, fy, cx, cy px; "
        "k1..k3, p1, p2; rx, ry, rz rad; tx, ty, tz m)."
    )
    rms: float = Field(description="RMS reprojection error of its detections, pixels.")
    poses_seen: int
    detections: int | None = Field(
        default=None,
        description="Images of the robot's markers it had (the top marker and the mast's): "
        "pose_residuals has one row per detection kept, detections - outliers.",
    )
    outliers: int = 0
    pose_residuals: list[list[float]] = Field(
        default_factory=list,
        description="Per detection used: [pose index, residual x px, residual y px] "
        "(projected minus detected).",
    )
    errors: NetworkCameraErrors = Field(description="Against the twin's true camera.")
    bound: NetworkCameraBound | None = None
    image_size: list[int]


class AccuracyCamera(ReadSchema):
    name: str
    errors: NetworkCameraErrors
    bound: NetworkCameraBound


class AccuracyRowRead(ReadSchema):
    """One drive of the accuracy study: true projections plus Gaussian noise of sigma_px."""

    stops: int = Field(description="Stops planned (poses: driven, with the second pass).")
    poses: int
    drive_s: float = Field(description="Simulated seconds of driving.")
    sigma_px: float = Field(description="Pixel noise standard deviation per axis, pixels.")
    cameras: list[AccuracyCamera]
    rejected: list[str]


class NetworkRegistration(ReadSchema):
    """The network moved into the world by the robot's marker where it read signposts."""

    signposts_read: int
    reason: str = Field("", description="Why it was not registered (empty when it was).")
    theta_deg: float | None = Field(None, description="Rotation about the vertical, degrees.")
    theta_std_deg: float | None = None
    t_m: list[float] | None = Field(None, description="Translation on the floor, metres.")
    sightings: int | None = Field(None, description="Signpost reads the ceiling also saw.")


class NetworkRunResult(ReadSchema):
    """What a network calibration produced: every calibrated camera, and those left out."""

    kind: Literal["network"]
    target: str
    poses: int = Field(description="Robot stops.")
    detections: int
    drive_s: float | None = Field(None, description="Simulated seconds of driving.")
    sigma_px: float | None = Field(
        None, description="Pixel noise of the detections measured against the truth, pixels."
    )
    intrinsics_from: str | None = None
    rms_px: float | None = Field(None, description="Joint reprojection RMS, pixels.")
    rms_whitened: float | None = Field(
        None, description="Joint RMS in units of the detections' standard deviations."
    )
    residual_variance: float | None = None
    pose_rms_px: list[float | None] = Field(
        default_factory=list, description="Reprojection RMS per stop over its cameras, pixels."
    )
    cameras: list[NetworkCameraResult]
    rejected: list[dict[str, Any]]
    accuracy: list[AccuracyRowRead] = Field(
        default_factory=list,
        description="Errors and Cramer-Rao bounds against drive length and pixel noise.",
    )
    registration: NetworkRegistration | None = Field(
        None, description="The signpost tour that registered the network to the world."
    )


# A camera placed from more clicked points than this is not being placed by hand.
MAX_PLACEMENT_POINTS = 1000


PlacementPixel = Annotated[
    list[Annotated[float, Field(ge=-1e5, le=1e5, allow_inf_nan=False)]],
    Field(min_length=2, max_length=2),
]
PlacementFloor = Annotated[
    list[Annotated[float, Field(ge=-1e4, le=1e4, allow_inf_nan=False)]],
    Field(min_length=2, max_length=2),
]


class PlacementPoint(Schema):
    """One pixel of the camera's image and the world point it shows."""

    pixel: PlacementPixel = Field(description="[u, v] in the camera's (distorted) pixels.")
    floor: PlacementFloor = Field(description="[x, y] on the floor plan, metres (world frame).")
    z: Annotated[float, Field(ge=-10, le=10, allow_inf_nan=False)] = Field(
        0.0, description="Height of the point above the floor, metres (0: on the floor)."
    )


class PlacementCreate(Schema):
    """Floor points of a camera: at least 4 pixels whose world positions are known."""

    points: Annotated[list[PlacementPoint], Field(min_length=1, max_length=MAX_PLACEMENT_POINTS)]
    apply: bool = Field(
        False, description="Apply the result to the camera at once (pose, and K when estimated)."
    )


class PlacementStd(ReadSchema):
    position_m: list[float] = Field(description="Of the camera's centre (x, y, z), metres.")
    rotation_deg: list[float] = Field(
        description="Of its orientation, as small rotations about the world's x, y, z, degrees."
    )
    f_px: float | None = Field(description="Of the focal length, pixels; null when K was known.")


class PlacementRunResult(ReadSchema):
    """A camera placed from floor points (core.calibration.place_camera)."""

    kind: Literal["placement"]
    camera_id: int
    T_world_camera: list[list[float]]
    K: list[list[float]]
    dist: list[float]
    f_estimated: bool = Field(description="Whether the focal length was estimated (no K known).")
    residuals_px: list[float] = Field(description="Per point, |projected - clicked|, pixels.")
    residuals: list[list[float]] = Field(description="Per point, projected - clicked [du, dv].")
    rejected: list[int] = Field(description="Indices of the points left out as wrong pairs.")
    rms: float = Field(description="RMS reprojection error of the points kept, pixels.")
    std: PlacementStd
    image_size: list[int]


class PlacementRead(ReadSchema):
    """The answer of POST /cameras/{id}/placement: the stored run's id, whether it was applied,
    and its result's pose, intrinsics, residuals and standard deviations."""

    run_id: int
    applied: bool
    T_world_camera: list[list[float]]
    K: list[list[float]]
    dist: list[float]
    f_estimated: bool
    residuals_px: list[float]
    residuals: list[list[float]]
    rejected: list[int]
    rms: float
    std: PlacementStd


class RunProgress(ReadSchema):
    """How far a run's current (or last) attempt has come."""

    stage: str = Field(description="What it is doing, e.g. 'detecting the chessboard'.")
    fraction: float = Field(ge=0, le=1, description="Share of the run done, 0 to 1.")


# The results of hand-eye runs (created by server.schemas.manipulation's HandEyeRunCreate) and
# projector runs (server.schemas.paths' ProjectorRunCreate), here so that one read model covers
# every kind.


class HandEyeMethodRow(ReadSchema):
    """One method's estimate on the same views, against the twin's truth."""

    method: str
    rotation_error_deg: float
    translation_error_mm: float
    rotation_std_deg: float
    translation_std_mm: float


class HandEyeRunResult(ReadSchema):
    """What a hand-eye run produced: X = T_ee_camera with its uncertainty and diagnostics."""

    kind: Literal["hand-eye"]
    arm_id: int
    source: Literal["twin", "poses"]
    method: str = Field(description="The linear method, '+refine' when refined.")
    X: list[list[float]] = Field(description="T_ee_camera, 4x4, metres.")
    covariance: list[list[float]] = Field(
        description="6x6 of a perturbation X exp(w, v): rotation rad then translation m, "
        "camera frame."
    )
    rotation_std_deg: float
    translation_std_m: float
    views: int
    motions: int = Field(description="Pairs of views used.")
    rotation_residuals_deg: list[float] = Field(description="Per motion, degrees.")
    translation_residuals_m: list[float] = Field(description="Per motion, metres.")
    refined: bool
    rms_px: float | None = Field(None, description="Reprojection RMS of the refinement, px.")
    per_view_rms_px: list[float] | None = None
    iterations: int = 0
    T_base_target: list[list[float]] = Field(description="The target in the arm's base frame.")
    seed: int | None = None
    sigma_px: float | None = Field(None, description="Twin: the pixel noise added, per axis.")
    rendered: bool | None = None
    truth: HandEyeMethodRow | None = Field(
        None, description="Twin: this result's errors against the twin's true hand-eye."
    )
    methods: list[HandEyeMethodRow] = Field(
        default_factory=list, description="Twin: every linear method on the same views."
    )


class ProjectorTwinErrors(ReadSchema):
    """The calibrated mount against the twin's true projector (scoring only)."""

    position_m: float
    rotation_deg: float
    aligned_position_m: float = Field(
        description="After removing the frame error of the cameras' own calibration."
    )
    aligned_rotation_deg: float
    tilt_offset_rad: float


class ProjectorRunResult(ReadSchema):
    """What a projector calibration produced: the mount, the tilt offset, their standard
    deviations, the floor RMS and the spots used, with the errors against the twin."""

    kind: Literal["projector"]
    projector_id: int
    T_world_projector: list[list[float]]
    tilt_offset_rad: float
    spots: int
    rms_m: float = Field(description="RMS floor distance of the located spots to the model's.")
    position_std_m: float
    rotation_std_deg: float
    spot_error_rms_m: float = Field(description="Located spots against the twin's, per axis.")
    cameras: list[str]
    camera_ids: list[int]
    spots_from: str
    twin_errors: ProjectorTwinErrors


class CalibrationRunRead(ReadSchema):
    """A calibration run of any kind: intrinsics, network, hand-eye (with its arm), projector
    or placement (a camera placed from floor points), with its status, progress and result."""

    id: int
    kind: str
    source: Literal["correspondences", "images", "twin", "poses", "points"]
    status: RunStatus
    camera_id: int | None
    arm_id: int | None = Field(None, description="A hand-eye run's arm.")
    options: dict[str, Any]
    result: (
        PlacementRunResult
        | CalibrationResult
        | NetworkRunResult
        | HandEyeRunResult
        | ProjectorRunResult
        | None
    )
    error: str | None
    created_at: UtcDatetime
    updated_at: UtcDatetime
    started_at: UtcDatetime | None = Field(description="When the current attempt began.")
    finished_at: UtcDatetime | None
    attempts: int = Field(
        0,
        description="How many times a worker claimed the run; more than one when a worker "
        "stopped (or died) during it and the run went back to the queue.",
    )
    lease_expires_at: UtcDatetime | None = Field(
        None,
        description="While running: when the claim lapses unless its worker renews it "
        "(it renews it every few seconds while alive).",
    )
    progress: RunProgress | None = Field(
        None, description="Stage and fraction reported by the running (or last) attempt."
    )

    @model_validator(mode="before")
    @classmethod
    def _progress_from_columns(cls, data: Any) -> Any:
        stage = getattr(data, "progress_stage", None)
        if stage is None or isinstance(data, dict):
            return data
        return {
            **{name: getattr(data, name) for name in cls.model_fields if name != "progress"},
            "progress": {"stage": stage, "fraction": data.progress_fraction or 0.0},
        }
