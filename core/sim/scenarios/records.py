"""The typed records the twin's scenarios return; each has `to_dict()` giving JSON-ready values."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Protocol

import numpy as np


@dataclass(frozen=True)
class CameraCalibrationError:
    """One camera's calibration against the twin: focal error in percent of the true
    (fx + fy) / 2 (signed, of the estimated (fx + fy) / 2), optical-centre position error
    metres, orientation error degrees (angle of R_est R_true^T), poses seen, reprojection RMS
    pixels (`rms_px`).

    Marker kind (None otherwise): `aligned_position_error_m`, `aligned_rotation_error_deg` the
    errors after removing the floor rigid motion (x, y, yaw) that best aligns all calibrated
    centres to the true ones (the network's own geometry, free of how well the odometry tied it
    to the start pose), and the Cramer-Rao bound of each of the five numbers (`bound_*`:
    standard deviation of the focal length in percent, root mean square position and
    orientation errors).

    Registered to the world by the signpost tour (core.sim.network_registration; None
    otherwise): `start_frame_position_error_m`, `start_frame_rotation_error_deg` the errors
    before it, in the frame the robot's start pose fixed; the `bound_*` of position and rotation
    are that frame's too.

    Board kind only (None otherwise): principal point error pixels (distance), and distortion
    error pixels: the largest difference between the estimated and the true lens distortion
    displacement, f_true |(D_est(x) - x) - (D_true(x) - x)| over ideal normalised rays x (the
    distortion alone, focal and principal point errors excluded), over the part of the image
    the board's detections covered (their convex hull; `distortion_error_px`) and over the
    whole image (`distortion_error_full_px`, extrapolated where the board never went: the
    image's upper part sees walls the robot cannot reach)."""

    name: str
    focal_error_pct: float
    position_error_m: float
    rotation_error_deg: float
    poses_seen: int
    rms_px: float
    aligned_position_error_m: float | None = None
    aligned_rotation_error_deg: float | None = None
    bound_focal_pct: float | None = None
    bound_position_m: float | None = None
    bound_rotation_deg: float | None = None
    bound_aligned_position_m: float | None = None
    bound_aligned_rotation_deg: float | None = None
    start_frame_position_error_m: float | None = None
    start_frame_rotation_error_deg: float | None = None
    principal_point_error_px: float | None = None
    distortion_error_px: float | None = None
    distortion_error_full_px: float | None = None


@dataclass(frozen=True)
class RejectedCameraReport:
    """A camera the calibration left out, with the reason."""

    name: str
    reason: str
    poses_seen: int


@dataclass(frozen=True)
class AccuracyRow:
    """One drive of an accuracy study: `seed`, `stops` planned for the first pass (`poses`
    driven, with the second pass), simulated `drive_s` seconds (within the study's budget),
    pixel noise `sigma_px` (true projections plus Gaussian noise), and the calibrated cameras'
    errors and bounds."""

    seed: int
    stops: int
    poses: int
    drive_s: float
    sigma_px: float
    cameras: tuple[CameraCalibrationError, ...]
    rejected: tuple[str, ...]


@dataclass(frozen=True)
class NetworkCalibrationResult:
    """Metrics of `network-calibration` (marker) and `network-calibration-board`.

    poses: robot stops; detections: camera-stop pairs seen; drive_s: simulated seconds of
    driving (None for the board kind, whose robot is placed at each stop); sigma_px: the pixel
    noise of the detections measured against the truth (RMS per axis); intrinsics_from: where
    each camera's intrinsics came from; distortion: how the lens distortion was treated;
    rms_px: the joint reprojection RMS over all detections, pixels; rms_whitened: the same in
    units of the detections' standard deviations; placement_sigma_m: the board kind's placement
    noise (None for the marker); `accuracy`: an accuracy study (errors and bounds as functions
    of drive length and pixel noise), empty unless asked for; `registration`: the signpost
    tour that registered the marker kind's network to the world (signposts declared, read and
    used, the rotation theta_deg with its standard deviation, the translation t_m, the RMS of
    the pairs' residuals, the tour's simulated seconds), None when not registered, with
    `registration_reason`."""

    scenario: str
    seed: int
    target_kind: str
    poses: int
    detections: int
    drive_s: float | None
    sigma_px: float
    intrinsics_from: str
    distortion: str
    rms_px: float
    rms_whitened: float
    cameras: tuple[CameraCalibrationError, ...]
    rejected: tuple[RejectedCameraReport, ...]
    placement_sigma_m: float | None = None
    accuracy: tuple[AccuracyRow, ...] = ()
    registration: dict[str, Any] | None = None
    registration_reason: str = ""

    def to_dict(self) -> dict[str, Any]:
        """Return the record as JSON-ready values."""
        return asdict(self)


@dataclass(frozen=True)
class LocalizationResult:
    """Metrics of `localization` / `localization-images`: samples located, pixel noise sigma
    (given, or measured from the detections), RMSE metres per estimator (mono, linear,
    constrained, ml) and the Cramer-Rao root mean trace for the cameras ML used.
    `cameras_from` says which cameras the estimators were given: "truth" (the twin's true
    cameras: these scenarios measure the estimators alone against the bound, without any
    calibration's error; the bound is computed on the same cameras)."""

    scenario: str
    seed: int
    samples: int
    sigma_px: float
    rmse_m: dict[str, float]
    crb_rmse_m: float
    measured_sigma_px: float | None = None
    cameras_from: str = "truth"

    def to_dict(self) -> dict[str, Any]:
        """Return the record as JSON-ready values."""
        return asdict(self)


class ScenarioResult(Protocol):
    """What every scenario returns (these records, and those of scenarios registered from
    other modules): its name, its seed and `to_dict()` giving JSON-ready values."""

    @property
    def scenario(self) -> str:
        """The scenario's registered name."""
        ...

    @property
    def seed(self) -> int:
        """The seed it ran with."""
        ...

    def to_dict(self) -> dict[str, Any]:
        """Return the record as JSON-ready values."""
        ...


def percentile_or_none(x: list[float], q: float) -> float | None:
    """Return the q-th percentile of x, None when x is empty (a figure with nothing to show)."""
    return float(np.percentile(x, q)) if x else None


def percent_or_none(k: int, n: int) -> float | None:
    """Return 100 k / n, None when n is 0."""
    return 100.0 * k / n if n else None
