"""Extrinsic calibration of the ceiling projector from commanded angles and located spots.

Data: joint angles q_i commanded to the projector and the floor points X_i (world x, y) where
the ceiling cameras located its spot, i = 1..N. Unknowns: the mount T_world_base (6 dof) and,
optionally, the tilt's zero offset. (A pan zero offset turns the beam about the pan axis
exactly as a turn of the mount about that axis does, so it is not identifiable beside a free
mount and is folded into the mount's orientation.)

1. Closed form. With the ideal model the beam leaves the base origin along d(q_i) (base
   frame), so the projector is a central "camera" whose rays are known: the normalised
   coordinates m_i = (d_x / d_z, d_y / d_z) and the floor points are related by the world-plane
   homography m ~ [r1 r2 t] (X, Y, 1), and the pose of the floor in the base frame follows by
   its decomposition with K = I and LM refinement (core.calibration.pose.estimate_plane_pose:
   Zhang 2000, sec. 3.1). T_world_base is its inverse.
2. Maximum likelihood. The floor distances sum_i |spot(q_i; T, offsets) - X_i|^2 are minimised
   over a local parametrisation T = T_0 [exp(omega) | v] (rotation omega (3) about the base's
   axes, translation v (3) in the world) and the tilt offset, by the sparse LM of core.optim
   (one residual block of 2 per spot, no local parameters; Jacobian by central differences
   of the vectorised forward model, accurate to ~1e-10 m/unit). Under i.i.d. Gaussian spot noise
   this is the ML estimate; its covariance is the inverse Gauss-Newton information times the
   spot variance (H&Z eq. A6.9), `spot_sigma`^2 when known, else the residual variance.

Degenerate sets are refused by name: fewer than 4 spots (the homography needs 4), spots
collinear or clustered (their spread's smaller principal axis under 5 % of the larger, or all
within 0.2 m of their centroid), beams above 80 degrees of tilt (the closed form's
normalised coordinates blow up).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_points
from core.calibration.pose import estimate_plane_pose
from core.errors import DegenerateConfiguration, InvalidInput, NotEnoughPoints
from core.geometry.rotations import matrix_to_rotvec, rotvec_to_matrix
from core.optim import solve_sparse_lm
from core.projector import PanTiltProjector

Array = NDArray[np.float64]

_MIN_SPREAD_RATIO = 0.05
_MIN_SPREAD_M = 0.2
_MAX_TILT = math.radians(80.0)
_FD_STEP = 1e-6


class DegenerateSpots(DegenerateConfiguration):
    """The spots do not determine the projector's mount (too few, collinear, clustered)."""


@dataclass(frozen=True)
class ProjectorCalibration:
    """The calibrated projector. `model` the projector with the estimated mount (and tilt
    offset); `T_world_base` (4, 4); `tilt_offset` rad (0 when not estimated); `rms` m the RMS
    floor distance per spot (sqrt(sum |r_i|^2 / N)); `residuals` (N, 2) m; `covariance` (p, p)
    of (omega (3) rad, v (3) m[, tilt offset rad]); `position_std` (3,) m, `rotation_std_deg`
    the RMS orientation uncertainty (sqrt of the trace of omega's covariance) in degrees;
    `iterations` of the LM."""

    model: PanTiltProjector
    T_world_base: Array
    tilt_offset: float
    rms: float
    residuals: Array = field(repr=False)
    covariance: Array = field(repr=False)
    position_std: Array
    rotation_std_deg: float
    iterations: int


def check_spot_set(spots: Array) -> None:
    """Raise DegenerateSpots when the floor points (N, 2) cannot calibrate a projector."""
    if len(spots) < 4:
        raise DegenerateSpots(
            f"{len(spots)} spots cannot fix the projector's mount; command at least 4 (12 or "
            "more spread over the floor for centimetre accuracy)"
        )
    c = spots - spots.mean(0)
    sv = np.linalg.svd(c, compute_uv=False)
    if np.sqrt(np.mean(np.sum(c * c, 1))) < _MIN_SPREAD_M:
        raise DegenerateSpots(
            "the spots are clustered (all within 0.2 m of their centre); spread them over "
            "the floor the projector reaches"
        )
    if sv[1] < _MIN_SPREAD_RATIO * sv[0]:
        raise DegenerateSpots(
            "the spots are (nearly) collinear: the mount's rotation about their line is not "
            "determined; add spots off that line"
        )


class _FloorDistance:
    """Residuals spot(q_i; params) - X_i for core.optim.solve_sparse_lm (one block per spot)."""

    def __init__(self, base: PanTiltProjector, q: Array, X: Array, offsets: bool) -> None:
        self.base, self.q, self.X, self.offsets = base, q, X, offsets
        self.p = 7 if offsets else 6

    def model(self, g: Array) -> PanTiltProjector:
        T = self.base.T_world_base.copy()
        T[:3, :3] = T[:3, :3] @ rotvec_to_matrix(g[:3])
        T[:3, 3] = T[:3, 3] + g[3:6]
        theta = self.base.theta.copy()
        if self.offsets:
            theta[1] += g[6]
        return replace(self.base, T_world_base=T, theta=theta)

    def residuals(self, x_global: Array, x_local: Array) -> Array:
        out: Array = self.model(x_global).spot(self.q, strict=False) - self.X
        return np.where(np.isfinite(out), out, 1e3)

    def jacobians(self, x_global: Array, x_local: Array) -> tuple[Array, Array, Array]:
        res = self.residuals(x_global, x_local)
        J = np.empty((len(self.X), 2, self.p))
        for k in range(self.p):
            d = np.zeros(self.p)
            d[k] = _FD_STEP
            J[:, :, k] = (
                self.residuals(x_global + d, x_local) - self.residuals(x_global - d, x_local)
            ) / (2 * _FD_STEP)
        return res, J, np.zeros((len(self.X), 2, 0))


def _initial_mount(nominal: PanTiltProjector, q: Array, X: Array) -> Array:
    ideal = replace(nominal, T_world_base=np.eye(4))
    d = ideal.beam(q).direction  # base frame
    if np.any(d[:, 2] < math.cos(_MAX_TILT)):
        raise DegenerateSpots(
            "some commanded beams are tilted beyond 80 degrees from the pan axis; command "
            "spots nearer the projector's foot"
        )
    m = d[:, :2] / d[:, 2:3]
    est = estimate_plane_pose(X, m, np.eye(3))
    T_base_floor = np.eye(4)
    T_base_floor[:3, :3], T_base_floor[:3, 3] = est.R, est.t
    T: Array = np.asarray(np.linalg.inv(T_base_floor), dtype=np.float64)
    return T


def calibrate_projector(
    nominal: PanTiltProjector,
    q: ArrayLike,
    spots: ArrayLike,
    *,
    spot_sigma: float | None = None,
    estimate_tilt_offset: bool = False,
    max_iterations: int = 50,
) -> ProjectorCalibration:
    """Return the projector's mount (and tilt offset) from commanded angles and located spots.

    nominal: the projector's model (its joint parameters and limits; its mount is only a
    fallback start); q: (N, 2) commanded (pan, tilt) rad; spots: (N, 2) world floor points
    (m) where the spots were located; spot_sigma: the spots' standard deviation per axis (m)
    when known (it scales the covariance). Minimises the floor distances (module docstring).
    Raises NotEnoughPoints, InvalidInput, DegenerateSpots, DegenerateConfiguration (an
    information matrix without full rank).
    """
    Q = as_points(q, 2, "q")
    X = as_points(spots, 2, "spots")
    if len(Q) != len(X):
        raise InvalidInput(f"q and spots differ in length: {len(Q)} and {len(X)}")
    if len(X) < 4:
        raise NotEnoughPoints(f"{len(X)} spots given; the projector's mount needs at least 4")
    check_spot_set(X)
    T0 = _initial_mount(nominal, Q, X)
    start = replace(nominal, T_world_base=T0)
    problem = _FloorDistance(start, Q, X, estimate_tilt_offset)
    sol = solve_sparse_lm(
        problem, np.zeros(problem.p), np.zeros((len(X), 0)), max_iterations=max_iterations
    )
    info = sol.information
    if np.linalg.cond(info) > 1e12:
        raise DegenerateConfiguration(
            "the spots do not determine the mount (information matrix singular); spread them "
            "over more tilt angles"
        )
    s2 = spot_sigma**2 if spot_sigma is not None else sol.residual_variance
    cov = np.asarray(s2 * np.linalg.inv(info), dtype=np.float64)
    model = problem.model(sol.x_global)
    res = problem.residuals(sol.x_global, np.zeros((len(X), 0)))
    return ProjectorCalibration(
        model=model,
        T_world_base=model.T_world_base,
        tilt_offset=float(sol.x_global[6]) if estimate_tilt_offset else 0.0,
        rms=float(np.sqrt(np.sum(res * res) / len(X))),
        residuals=res,
        covariance=cov,
        position_std=np.sqrt(np.diag(cov)[3:6]),
        rotation_std_deg=math.degrees(math.sqrt(float(np.trace(cov[:3, :3])))),
        iterations=sol.iterations,
    )


def mount_errors(estimated: ArrayLike, true: ArrayLike) -> tuple[float, float]:
    """Return (position error m, rotation error deg) between two mounts T_world_base."""
    A, B = np.asarray(estimated, np.float64), np.asarray(true, np.float64)
    dR = A[:3, :3] @ B[:3, :3].T
    ang = float(np.linalg.norm(matrix_to_rotvec(dR[None])[0]))
    return float(np.linalg.norm(A[:3, 3] - B[:3, 3])), math.degrees(ang)
