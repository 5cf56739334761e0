"""The robot's odometry between calibration stops as a prior: increments and their covariance.

A wheeled base reports its pose by integrating what its wheels executed; the true motion departs
from it by wheel slip, modelled per integration step of forward distance ds and turn dyaw as
independent Gaussian errors (Thrun, Burgard & Fox, Probabilistic Robotics, sec. 5.4):

    along track  e_s ~ N(0, a^2 |ds|),   lateral  e_l ~ N(0, b^2 |ds|),
    heading      e_h ~ N(0, c^2 |ds| + d^2 |dyaw|),

applied with the midpoint heading h = yaw + dyaw / 2 (the twin's unicycle, core.sim.motion).
Between two stops the slip of the steps in between accumulates into the error of the relative
motion (the *increment*) from the first stop to the second, expressed in the first stop's
frame; increments of different segments are independent, because they are made of different
steps. The absolute poses, the start pose composed with the increments, then have the
correlated covariance of a random walk. So the calibration takes as unknowns the corrections
eps_j of the increments, each with its own 3 x 3 prior: exactly the absolute poses with their
correlated prior, but with a block-diagonal information.

First-order propagation over the steps k of a segment ending at pose b (world-aligned errors):

    delta_b = sum_k Phi(b <- k) G_k e_k,   Phi(b <- k) = [[I, J (p_b - p_k)], [0, 1]],
    G_k = [[cos h, -sin h, -ds sin h / 2], [sin h, cos h, ds cos h / 2], [0, 0, 1]],

J the 90 degree turn, p_k the position after step k; then rotated into the segment's first
frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import InvalidInput
from core.geometry.rotations import wrap_angle

Array = NDArray[np.float64]

_TURN = np.array([[0.0, -1.0], [1.0, 0.0]])


@dataclass(frozen=True)
class SlipModel:
    """Wheel-slip standard deviations: `distance_per_sqrt_m` (m per sqrt(m) travelled, along
    track), `lateral_per_sqrt_m` (m per sqrt(m)), `heading_per_sqrt_m` (rad per sqrt(m)),
    `heading_per_sqrt_rad` (rad per sqrt(rad) turned)."""

    distance_per_sqrt_m: float
    lateral_per_sqrt_m: float
    heading_per_sqrt_m: float
    heading_per_sqrt_rad: float


@dataclass(frozen=True)
class OdometryPrior:
    """The recorded motion from a known start pose to M stops, as independent increments.

    start (3,): the start pose (x m, y m, yaw rad), which defines the world frame; increments
    (M, 3): the relative motion (dx m, dy m, dyaw rad) from the previous stop (the start for
    the first) to stop j, in the previous stop's frame; cov (M, 3, 3) their covariance.
    """

    start: Array
    increments: Array
    cov: Array

    @property
    def poses(self) -> Array:
        """The recorded poses (M, 3) of the stops, (x m, y m, yaw rad)."""
        return compose_increments(self.start, self.increments)

    def pose_covariance(self) -> Array:
        """Return the correlated covariance (3 M, 3 M) of the recorded poses, first order."""
        D = increment_jacobian(self.start, self.increments).reshape(3 * len(self.cov), -1)
        Q = np.zeros((D.shape[1], D.shape[1]))
        for j, c in enumerate(self.cov):
            Q[3 * j : 3 * j + 3, 3 * j : 3 * j + 3] = c
        return np.asarray(D @ Q @ D.T)


def compose_increments(start: ArrayLike, increments: ArrayLike) -> Array:
    """Return the poses (M, 3) reached from `start` (3,) by the increments (M, 3), each in the
    frame of the pose before it: yaw_j = yaw_0 + sum dyaw, p_j = p_{j-1} + R(yaw_{j-1}) dp_j."""
    s = np.asarray(start, dtype=np.float64)
    inc = np.asarray(increments, dtype=np.float64).reshape(-1, 3)
    yaw = s[2] + np.cumsum(inc[:, 2])
    prev = np.concatenate([[s[2]], yaw[:-1]])
    c, sn = np.cos(prev), np.sin(prev)
    step = np.stack([c * inc[:, 0] - sn * inc[:, 1], sn * inc[:, 0] + c * inc[:, 1]], 1)
    xy = s[:2] + np.cumsum(step, axis=0)
    return np.column_stack([xy, yaw])


def increment_jacobian(start: ArrayLike, increments: ArrayLike) -> Array:
    """Return d pose_j / d increment_k (M, 3, M, 3) (zero for k > j).

    An increment k moves pose k by (R(yaw_{k-1}) d_xy, d_yaw); a heading change at pose k turns
    every later position about p_k: d p_j / d yaw_k = J (p_j - p_k).
    """
    s = np.asarray(start, dtype=np.float64)
    inc = np.asarray(increments, dtype=np.float64).reshape(-1, 3)
    P = compose_increments(s, inc)
    M = len(P)
    prev = np.concatenate([[s[2]], P[:-1, 2]])
    c, sn = np.cos(prev), np.sin(prev)
    low = np.tril(np.ones((M, M)))  # [j, k] = 1 for k <= j
    D = np.zeros((M, 3, M, 3))
    D[:, 0, :, 0] = low * c
    D[:, 0, :, 1] = -low * sn
    D[:, 1, :, 0] = low * sn
    D[:, 1, :, 1] = low * c
    diff = P[:, None, :2] - P[None, :, :2]  # [j, k] = p_j - p_k
    D[:, 0, :, 2] = -low * diff[..., 1]
    D[:, 1, :, 2] = low * diff[..., 0]
    D[:, 2, :, 2] = low
    return D


def odometry_prior(odometry: ArrayLike, stops: ArrayLike, slip: SlipModel) -> OdometryPrior:
    """Return the odometry between stops as a prior (module docstring).

    odometry: (N, 3) the base's odometry poses (x m, y m, yaw rad) at every integration step,
    row 0 the start; stops: (M,) increasing row indices (>= 1) of the stops; slip: the base's
    slip model. Raises InvalidInput for bad shapes, non-finite values or unordered stops.
    """
    odo = np.asarray(odometry, dtype=np.float64)
    idx = np.asarray(stops, dtype=np.int64).reshape(-1)
    if odo.ndim != 2 or odo.shape[1] != 3 or not np.all(np.isfinite(odo)):
        raise InvalidInput(f"odometry must be finite, shape (N, 3); got {odo.shape}")
    if len(idx) == 0 or idx[0] < 1 or np.any(np.diff(idx) <= 0) or idx[-1] >= len(odo):
        raise InvalidInput(
            f"stops must be increasing row indices in 1..{len(odo) - 1}; got {idx.tolist()[:8]}"
        )
    a, b = slip.distance_per_sqrt_m, slip.lateral_per_sqrt_m
    c, d = slip.heading_per_sqrt_m, slip.heading_per_sqrt_rad
    dp = np.diff(odo[:, :2], axis=0)
    dyaw = wrap_angle(np.diff(odo[:, 2]))
    h = odo[:-1, 2] + 0.5 * dyaw
    ch, sh = np.cos(h), np.sin(h)
    ds = dp[:, 0] * ch + dp[:, 1] * sh
    n = len(ds)
    G = np.zeros((n, 3, 3))
    G[:, 0, 0], G[:, 0, 1], G[:, 0, 2] = ch, -sh, -0.5 * ds * sh
    G[:, 1, 0], G[:, 1, 1], G[:, 1, 2] = sh, ch, 0.5 * ds * ch
    G[:, 2, 2] = 1.0
    q = np.stack(
        [a * a * np.abs(ds), b * b * np.abs(ds), c * c * np.abs(ds) + d * d * np.abs(dyaw)]
    )
    # The end of each step's segment: step k (from row k to k + 1) belongs to the segment that
    # ends at the first stop row >= k + 1.
    seg = np.searchsorted(idx, np.arange(1, n + 1), side="left")
    inside = seg < len(idx)
    end = odo[idx[np.minimum(seg, len(idx) - 1)], :2]
    lever = end - odo[1:, :2]
    Phi = np.tile(np.eye(3), (n, 1, 1))
    Phi[:, :2, 2] = lever @ _TURN.T
    A = Phi @ G
    contrib = np.einsum("nik,nk,njk->nij", A, q.T, A)
    cov_w = np.zeros((len(idx), 3, 3))
    np.add.at(cov_w, seg[inside], contrib[inside])
    first = np.concatenate([[0], idx[:-1]])
    yaw0 = odo[first, 2]
    R = np.zeros((len(idx), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1] = (
        np.cos(yaw0),
        np.sin(yaw0),
        -np.sin(yaw0),
        np.cos(yaw0),
    )
    R[:, 2, 2] = 1.0  # R^T of the first frame: world-aligned errors into that frame
    cov = R @ cov_w @ R.transpose(0, 2, 1)
    rel = odo[idx, :2] - odo[first, :2]
    inc = np.column_stack(
        [
            np.cos(yaw0) * rel[:, 0] + np.sin(yaw0) * rel[:, 1],
            -np.sin(yaw0) * rel[:, 0] + np.cos(yaw0) * rel[:, 1],
            wrap_angle(odo[idx, 2] - yaw0),
        ]
    )
    # A segment without motion has zero covariance; a floor keeps the prior invertible.
    cov = cov + np.eye(3) * 1e-12
    return OdometryPrior(start=odo[0].copy(), increments=inc, cov=cov)
