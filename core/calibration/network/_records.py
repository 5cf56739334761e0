"""The records every network calibration returns: calibrated and rejected cameras."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from core.geometry.rotations import rotvec_to_matrix

Array = NDArray[np.float64]


@dataclass(frozen=True)
class CalibratedCamera:
    """One camera of the network after calibration.

    K (3, 3) pixels; dist (5,) OpenCV (k1, k2, p1, p2, k3); R (3, 3) = R_camera_world,
    t (3,) = t_camera_world metres (Xc = R X + t). `std` the standard deviations of the refined
    parameters named by `parameter_names` (pixels for fx, fy, cx, cy; unitless distortion;
    rvec rad; t m) and `covariance` their covariance, from the joint Gauss-Newton information
    scaled by the measured residual variance (H&Z eq. A6.9 with sigma^2 estimated as
    SSE / (N - d)); `residuals` (N, 2) pixels (projected - detected) of the N detections
    (marker centres or board corners) used, and `pose_index` (N,) the robot pose each belongs
    to; `initial_K`, `initial_R`, `initial_t`: the estimate before the joint refinement;
    `poses_seen`: robot poses detected; `outliers`: detections (board kind: views) dropped as
    inconsistent; `detections` (marker kind): the markers' images it had, of every marker the
    robot carries (0 when not counted).
    """

    name: str
    K: Array
    dist: Array
    R: Array
    t: Array
    std: Array = field(repr=False)
    residuals: Array = field(repr=False)
    poses_seen: int
    outliers: int
    initial_K: Array = field(repr=False)
    initial_R: Array = field(repr=False)
    initial_t: Array = field(repr=False)
    parameter_names: tuple[str, ...] = ("f", "rx", "ry", "rz", "tx", "ty", "tz")
    pose_index: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64), repr=False)
    covariance: Array = field(default_factory=lambda: np.zeros((0, 0)), repr=False)
    detections: int = 0

    @classmethod
    def refined(
        cls,
        name: str,
        params: tuple[Array, Array, Array, Array],
        initial: tuple[Array, Array, Array, Array],
        covariance: Array,
        block: slice,
        *,
        residuals: Array,
        poses_seen: int,
        outliers: int,
        parameter_names: tuple[str, ...],
        pose_index: NDArray[np.int64],
        detections: int = 0,
    ) -> CalibratedCamera:
        """Return a camera of a joint refinement: its refined and initial parameters (K, dist,
        rotation vector, t), and its block of the refinement's global covariance (`std` its
        diagonal's roots, negative round-off clipped to zero)."""
        K, d, rv, t = params
        K0, _, rv0, t0 = initial
        return cls(
            name=name,
            K=K,
            dist=d,
            R=rotvec_to_matrix(rv),
            t=t.copy(),
            std=np.sqrt(np.maximum(np.diag(covariance)[block], 0.0)),
            residuals=residuals,
            pose_index=pose_index,
            covariance=covariance[block, block].copy(),
            poses_seen=poses_seen,
            outliers=outliers,
            initial_K=K0,
            initial_R=rotvec_to_matrix(rv0),
            initial_t=t0.copy(),
            parameter_names=parameter_names,
            detections=detections,
        )

    @property
    def focal(self) -> float:
        """Focal length f in pixels, (fx + fy) / 2 (fx = fy for the marker kind)."""
        return float(0.5 * (self.K[0, 0] + self.K[1, 1]))

    @property
    def position(self) -> Array:
        """Optical centre in the world (3,), metres."""
        return -self.R.T @ self.t

    @property
    def T_world_camera(self) -> Array:
        """Pose (4, 4) mapping camera coordinates to world coordinates."""
        T = np.eye(4)
        T[:3, :3] = self.R.T
        T[:3, 3] = self.position
        return T

    @property
    def rms(self) -> float:
        """Root mean square reprojection error per detection, pixels."""
        if len(self.residuals) == 0:
            return float("nan")
        return float(np.sqrt(np.mean(np.sum(self.residuals**2, axis=1))))

    def pose_rms(self, poses: int) -> Array:
        """Return the RMS reprojection error (pixels) of each of `poses` robot poses (M,) in
        this camera, NaN where it has no detection."""
        sq = np.bincount(self.pose_index, np.sum(self.residuals**2, axis=1), minlength=poses)
        n = np.bincount(self.pose_index, minlength=poses)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(n > 0, np.sqrt(sq / np.maximum(n, 1)), np.nan)


@dataclass(frozen=True)
class RejectedCamera:
    """A camera left out of the calibration: its name, why, and how many poses it saw."""

    name: str
    reason: str
    poses_seen: int


@dataclass(frozen=True)
class NetworkCalibration:
    """The calibrated network: `cameras` (calibrated), `rejected` (by name with the reason),
    `targets` the refined robot poses (M, 3) (x m, y m, yaw rad) and `target_cov` (M, 3, 3)
    their covariance (the prior's where no camera saw the pose). `rms_px`: the reprojection
    RMS over every detection used, pixels; `rms_whitened`: the RMS of the residuals divided by
    their standard deviations (unitless, about 1 when the pixel covariances are right);
    `residual_variance`: the estimated variance factor SSE / (N - d) of the whitened residuals
    (pixel and prior rows) that scales every covariance; LM `iterations`."""

    cameras: tuple[CalibratedCamera, ...]
    rejected: tuple[RejectedCamera, ...]
    targets: Array = field(repr=False)
    target_cov: Array = field(repr=False)
    rms_px: float
    rms_whitened: float
    residual_variance: float
    iterations: int

    @property
    def poses(self) -> int:
        """Number of robot poses M."""
        return len(self.targets)

    @property
    def pose_rms_px(self) -> Array:
        """Per-pose reprojection RMS (M,) pixels over every camera that saw the pose (NaN where
        none did)."""
        M = self.poses
        sq, n = np.zeros(M), np.zeros(M)
        for c in self.cameras:
            sq += np.bincount(c.pose_index, np.sum(c.residuals**2, axis=1), minlength=M)
            n += np.bincount(c.pose_index, minlength=M)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(n > 0, np.sqrt(sq / np.maximum(n, 1)), np.nan)

    def camera(self, name: str) -> CalibratedCamera:
        """Return the calibrated camera called `name`; raise InvalidInput otherwise."""
        for c in self.cameras:
            if c.name == name:
                return c
        why = {r.name: r.reason for r in self.rejected}.get(name, "unknown camera")
        raise InvalidInput(f"camera {name!r} is not calibrated: {why}")
