"""The mobile manipulator as one kinematic chain: world -> base (x, y, theta) -> arm mount ->
arm joints -> end effector -> eye-in-hand camera.

The differential-drive base enters the chain as three planar joints (prismatic x, y, revolute
theta about the world's z axis), as in the "generalised manipulator" of spec 05: its
nonholonomy constrains how the base gets to a pose, not which poses exist, so inverse
kinematics may treat it as holonomic and the base's planner drives there. Configuration
vector x = (x, y, theta, q1..q6): metres and radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import InvalidInput
from core.geometry.poses import as_pose, invert_pose, planar_pose, pose_error
from core.manipulation.arm import DHArm
from core.manipulation.arm_models import default_arm
from core.manipulation.errors import Unreachable
from core.manipulation.numerical_ik import (
    IKResult,
    levenberg_marquardt,
    pose_residual,
    rotvec_one,
)

Array = NDArray[np.float64]

# The base's x, y are unbounded; finite stand-ins keep the limit arithmetic finite.
_FREE = 1e6


@dataclass(frozen=True)
class BasePlacement:
    """A base pose from which the arm reaches a target: base (3,) = (x, y, theta); q (6,) the
    arm's joint values (a closed-form branch within limits); travel (m) from the current base
    position; manipulability of the arm there (Yoshikawa's measure)."""

    base: Array
    q: Array
    travel: float
    manipulability: float

    @property
    def x(self) -> Array:
        """The whole chain's configuration (9,) = (x, y, theta, q1..q6)."""
        return np.concatenate([self.base, self.q])


@dataclass(frozen=True, eq=False)
class MobileManipulator:
    """The arm on the differential-drive base, with its eye-in-hand camera.

    arm: the DH arm; T_base_arm (4, 4): the arm's base frame in the robot's base frame (x
    forward, y left, z up, origin on the floor under the base centre); T_ee_camera (4, 4): the
    eye-in-hand camera (OpenCV frame: x right, y down, z forward) in the end effector's frame.
    """

    arm: DHArm = field(default_factory=default_arm)
    T_base_arm: Array = field(default_factory=lambda: _mount())
    T_ee_camera: Array = field(default_factory=lambda: _camera_mount())

    def __post_init__(self) -> None:
        object.__setattr__(self, "T_base_arm", as_pose(self.T_base_arm, "T_base_arm"))
        object.__setattr__(self, "T_ee_camera", as_pose(self.T_ee_camera, "T_ee_camera"))

    @property
    def limits(self) -> Array:
        """Joint limits (9, 2): the base's x, y and theta are free (+-1e6), then the arm's."""
        free = np.array([[-_FREE, _FREE]] * 3)
        return np.concatenate([free, self.arm.limits])

    def _check_x(self, x: ArrayLike) -> Array:
        a = np.asarray(x, dtype=np.float64)
        if a.shape[-1:] != (9,) or not np.all(np.isfinite(a)):
            raise InvalidInput(
                f"x must be finite configurations (..., 9) = (x, y, theta, q1..q6), got {a.shape}"
            )
        return a

    def arm_base(self, x: ArrayLike) -> Array:
        """Return T_world_arm (..., 4, 4): the arm's base frame for configurations (..., 9)."""
        a = self._check_x(x)
        return planar_pose(a[..., :3]) @ self.T_base_arm

    def fk(self, x: ArrayLike) -> Array:
        """Return T_world_ee (..., 4, 4) for configurations x (..., 9)."""
        a = self._check_x(x)
        return self.arm_base(a) @ self.arm.fk(a[..., 3:])

    def camera_pose(self, x: ArrayLike) -> Array:
        """Return T_world_camera (..., 4, 4) of the eye-in-hand camera for configurations x."""
        return self.fk(x) @ self.T_ee_camera

    def jacobian(self, x: ArrayLike) -> Array:
        """Return the geometric Jacobian (..., 6, 9) of the end effector in the world frame,
        rows (v, omega), columns (x, y, theta, q1..q6): the base's prismatic columns (e_x, 0),
        (e_y, 0), its revolute column (e_z x (p - b), e_z), then the arm's Jacobian rotated
        into the world by R_world_arm (its velocity reference point is the same end effector)."""
        a = self._check_x(x)
        Tw = self.arm_base(a)
        Ja = self.arm.jacobian(a[..., 3:])
        T = Tw @ self.arm.fk(a[..., 3:])
        R = Tw[..., :3, :3]
        J = np.zeros((*a.shape[:-1], 6, 9))
        J[..., 0, 0] = 1.0
        J[..., 1, 1] = 1.0
        J[..., 0, 2] = -(T[..., 1, 3] - a[..., 1])
        J[..., 1, 2] = T[..., 0, 3] - a[..., 0]
        J[..., 5, 2] = 1.0
        J[..., :3, 3:] = R @ Ja[..., :3, :]
        J[..., 3:, 3:] = R @ Ja[..., 3:, :]
        return J

    def _kinematics_one(self, x: Array) -> tuple[Array, Array, Array]:
        """(p (3,), R (3, 3), J (6, 9)) of one configuration, for the LM."""
        c, s = math.cos(x[2]), math.sin(x[2])
        Rb = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        Rw = Rb @ self.T_base_arm[:3, :3]
        tw = Rb @ self.T_base_arm[:3, 3] + np.array([x[0], x[1], 0.0])
        p, R, Ja = self.arm._kinematics_one(x[3:])
        pw = Rw @ p + tw
        J = np.zeros((6, 9))
        J[0, 0] = J[1, 1] = J[5, 2] = 1.0
        J[0, 2] = -(pw[1] - x[1])
        J[1, 2] = pw[0] - x[0]
        J[:3, 3:] = Rw @ Ja[:3]
        J[3:, 3:] = Rw @ Ja[3:]
        return pw, Rw @ R, J

    def ik(
        self,
        T_world_ee: ArrayLike,
        x0: ArrayLike,
        *,
        base_weight: float = 10.0,
        limit_weight: float = 1.0,
        tol: float = 1e-10,
        redundancy_iterations: int = 60,
        max_iterations: int = 400,
        max_restarts: int = 12,
        rng: np.random.Generator | int | None = 0,
    ) -> IKResult:
        """Return a whole-chain configuration (9,) reaching T_world_ee, starting from x0 (9,).

        Redundancy (9 joints, 6 constraints) is resolved by weighted damped least squares with
        a null-space objective (Nakamura, "Advanced Robotics: Redundancy and Optimization",
        1991, ch. 4; Chan & Dubey, IEEE T-RA 11(2), 1995): steps
        dx = W^-1 J^T (J W^-1 J^T + mu I)^-1 e + (I - J_W^+ J) z, W = diag(base_weight (x3),
        1 (x6)) so the base moves little, and z = -grad h, h = base_weight |b - b0|^2 +
        limit_weight sum_i ((q_i - mid_i) / range_i)^2 (stay away from the base's start and
        from the arm's limits; singularities are avoided by the damping). Then Levenberg-
        Marquardt with the same weights polishes the pose to `tol`; when it stops at an arm
        limit it restarts (up to `max_restarts`) with the base kept and the arm from the arm's
        nearest seed configurations, then random ones from `rng`. The errors reported are
        recomputed from fk.
        """
        Tm = as_pose(T_world_ee, "T_world_ee")
        if Tm.shape != (4, 4):
            raise InvalidInput(f"T_world_ee must be one (4, 4) pose, got {Tm.shape}")
        x = np.clip(self._check_x(x0).astype(np.float64).copy(), *self.limits.T)
        if x.shape != (9,):
            raise InvalidInput(f"x0 must be one configuration (9,), got {x.shape}")
        lim = self.limits
        lo, hi = lim[:, 0], lim[:, 1]
        mid = (self.arm.limits[:, 0] + self.arm.limits[:, 1]) / 2
        rng_ = self.arm.limits[:, 1] - self.arm.limits[:, 0]
        w = np.concatenate([np.full(3, base_weight), np.ones(6)])
        w_inv = 1.0 / w
        b0 = x[:3].copy()
        pt, Rt = Tm[:3, 3], Tm[:3, :3]
        iters = 0
        for _ in range(redundancy_iterations):
            p, R, J = self._kinematics_one(x)
            e = np.concatenate([pt - p, rotvec_one(Rt @ R.T)])
            JW = J * w_inv
            M = JW @ J.T + 1e-6 * np.eye(6)
            task = JW.T @ np.linalg.solve(M, e)
            grad = np.zeros(9)
            grad[:3] = 2.0 * base_weight * (x[:3] - b0)
            grad[3:] = 2.0 * limit_weight * (x[3:] - mid) / rng_**2
            z = -0.5 * grad * w_inv
            # The weighted null-space projector I - W^-1 J^T M^-1 J.
            null = z - JW.T @ np.linalg.solve(M, J @ z)
            step = task + null
            # Keep each step small: the task error is linearised.
            scale = min(1.0, 0.3 / max(float(np.abs(step).max()), 1e-300))
            x = np.clip(x + scale * step, lo, hi)
            iters += 1
            if float(e @ e) < 1e-8 and float(null @ null) < 1e-12:
                break
        periodic = np.array([False, False, True] + [True] * 6)
        gen = np.random.default_rng(rng)
        restarts = 0
        residual = pose_residual(self._kinematics_one, Tm)
        xf, cost, used, ok = levenberg_marquardt(
            residual, x, lo, hi, w, tol, max_iterations, periodic=periodic
        )
        iters += used
        # A polish stuck at an arm limit restarts from the arm's nearest seeds at the base
        # reached, then from random arm configurations: the base stays where it was.
        starts = self.arm._nearest_seeds(invert_pose(self.arm_base(x)) @ Tm, 4)
        while not ok and iters < max_iterations and restarts < max_restarts:
            xs = x.copy()
            xs[3:] = starts.pop(0) if starts else gen.uniform(*self.arm.limits.T)
            restarts += 1
            xr, cr, used, ok = levenberg_marquardt(
                residual,
                xs,
                lo,
                hi,
                w,
                tol,
                max_iterations - iters,
                periodic=periodic,
            )
            iters += used
            if cr < cost:
                xf, cost = xr, cr
        dp, dr = pose_error(self.fk(xf), Tm)
        return IKResult.from_errors(xf, dp, dr, tol, iters, restarts)

    def place_base(
        self,
        T_world_ee: ArrayLike,
        current: ArrayLike,
        *,
        radii: ArrayLike = (0.35, 0.45, 0.55, 0.65, 0.75),
        bearings: int = 24,
        yaw_offsets: ArrayLike = (-0.5, -0.25, 0.0, 0.25, 0.5),
        min_manipulability: float = 1e-3,
        candidates: ArrayLike | None = None,
    ) -> BasePlacement:
        """Return a base pose from which the arm reaches T_world_ee within its limits.

        Candidates: the base centre at each radius (m) and bearing around the target's floor
        point, facing it up to each yaw offset (rad). Each candidate's arm target
        T_arm_ee = (T_world_base T_base_arm)^-1 T_world_ee is solved in closed form; among the
        branches within limits with manipulability above `min_manipulability`, the one
        minimising travel from `current` (x, y, theta) minus 0.5 m per unit of manipulability
        wins. `candidates` (K, 3) base poses replace the ring (e.g. poses known to be free of
        furniture). Collisions with furniture are not checked. Raises Unreachable when no
        candidate reaches the target.
        """
        Tm = as_pose(T_world_ee, "T_world_ee")
        cur = np.asarray(current, dtype=np.float64)
        if cur.shape != (3,) or not np.all(np.isfinite(cur)):
            raise InvalidInput(f"current must be the base pose (x, y, theta), got {cur.shape}")
        target = Tm[:2, 3]
        if candidates is None:
            ring = []
            for r in np.asarray(radii, dtype=np.float64):
                for k in range(int(bearings)):
                    phi = 2 * math.pi * k / bearings
                    pos = target - r * np.array([math.cos(phi), math.sin(phi)])
                    for dyaw in np.asarray(yaw_offsets, dtype=np.float64):
                        ring.append([pos[0], pos[1], phi + dyaw])
            cands = np.array(ring)
        else:
            cands = np.asarray(candidates, dtype=np.float64)
            if cands.ndim != 2 or cands.shape[1] != 3 or not np.all(np.isfinite(cands)):
                raise InvalidInput(
                    f"candidates must be finite (K, 3) base poses, got {cands.shape}"
                )
        best: BasePlacement | None = None
        best_score = np.inf
        for base in cands:
            travel = float(np.linalg.norm(base[:2] - cur[:2]))
            if travel - 0.5 > best_score:
                continue
            T_arm = invert_pose(planar_pose(base) @ self.T_base_arm) @ Tm
            for q in self.arm.ik_analytic(T_arm, include_singular=False):
                mu = float(self.arm.manipulability(q))
                if mu < min_manipulability:
                    continue
                score = travel - 0.5 * mu
                if score < best_score:
                    best_score = score
                    best = BasePlacement(base.copy(), q, travel, mu)
        if best is None:
            raise Unreachable(
                "no base pose reaches the target with the arm inside its limits; the target "
                f"at height {Tm[2, 3]:.2f} m may be out of the arm's vertical range, or its "
                "orientation unreachable"
            )
        return best


def _mount() -> Array:
    """The arm's shoulder 0.80 m above the floor (on a column), 0.05 m ahead of the base centre:
    level with a table top, so the gripper reaches down onto tables and counters."""
    T = np.eye(4)
    T[:3, 3] = [0.05, 0.0, 0.80]
    return T


def _camera_mount() -> Array:
    """The eye-in-hand camera 0.06 m off the gripper axis (along the gripper's x) and 0.08 m
    behind the fingertips, its optical axis along the gripper's approach (z) tilted 10 degrees
    towards that axis, rolled 90 degrees so the image's x runs along the gripper's y."""
    t = math.radians(-10.0)
    roll = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    tilt = np.array(
        [[1.0, 0.0, 0.0], [0.0, math.cos(t), -math.sin(t)], [0.0, math.sin(t), math.cos(t)]]
    )
    T = np.eye(4)
    T[:3, :3] = roll @ tilt
    T[:3, 3] = [0.06, 0.0, -0.08]
    return T


def default_manipulator() -> MobileManipulator:
    """Return the twin's mobile manipulator: `default_arm()` mounted with its shoulder 0.80 m
    above the floor and the eye-in-hand camera beside the gripper."""
    return MobileManipulator()
