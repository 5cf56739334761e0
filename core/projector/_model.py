"""The pan-tilt laser projector: Denavit-Hartenberg chain, spot on the floor, aiming, Jacobian.

Frames. The base frame is fixed to the ceiling mount; `T_world_base` (4x4) maps base
coordinates to the world (Z up, floor Z = 0). The pan axis is the base's z axis. Each joint i
(1 = pan, 2 = tilt) is a standard Denavit-Hartenberg link (Spong, Hutchinson & Vidyasagar,
"Robot Modeling and Control", sec. 3.2):

    A_i(q_i) = Rot_z(q_i + theta_i) Trans_z(d_i) Trans_x(a_i) Rot_x(alpha_i),

and the beam leaves the origin of frame 2 shifted by `beam_origin` (frame-2 coordinates) along
the frame-2 direction b = (0, -1, 0). The ideal projector (every offset zero, alpha_1 = -pi/2)
points its beam along the base's z axis at zero tilt and, in general, along

    d(q) = (sin q2 cos q1, sin q2 sin q1, cos q2)         (base frame),

so a ceiling mount with base z pointing down (`T_world_base` rotating z to -Z) puts the spot
straight below at q = (0, 0). `theta` (joint zero offsets), `d`, `a` and `beam_origin` hold the
small offsets of a real unit; `alpha_1` departs from -pi/2 by the axes' non-orthogonality.

The spot is where the beam line o + l d (l > 0) meets the floor plane Z = `floor_height`
(H&Z eq. 6.14's ray-plane intersection). A beam with d_Z >= 0 never comes down: above the
horizon; one whose intersection lies behind the origin misses the floor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_matrix
from core.errors import DegenerateConfiguration, IntspaceError, InvalidInput
from core.geometry.rotations import wrap_angle

Array = NDArray[np.float64]

# The beam must descend at least this steeply (d_Z <= -_MIN_DESCENT) to hit the floor: at
# 1e-6 the spot of a 3 m high unit is 3 km away, far beyond any plan.
_MIN_DESCENT = 1e-6
# Newton's iterations for aim(): quadratic convergence from the closed form needs 3-5.
_NEWTON_ITERATIONS = 30
# |tilt| below this (radians) is the pan singularity: the pan axis and the beam coincide.
SINGULAR_TILT = 1e-6


class BeamAboveHorizon(IntspaceError, ValueError):
    """The beam points level or upwards: it never reaches the floor."""


class BeamMissesFloor(IntspaceError, ValueError):
    """The beam's line meets the floor plane only behind its origin (e.g. a unit below Z = 0)."""


class UnreachablePoint(IntspaceError, ValueError):
    """No joint angles within the limits aim the beam at this floor point."""


class SingularConfiguration(DegenerateConfiguration):
    """The beam is (nearly) along the pan axis: pan does not move the spot."""


def _dh(theta: Array, d: float, a: float, alpha: float) -> Array:
    """Return the DH link transforms (..., 4, 4) for joint angles theta (...)."""
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = math.cos(alpha), math.sin(alpha)
    T = np.zeros((*theta.shape, 4, 4))
    T[..., 0, 0] = ct
    T[..., 0, 1] = -st * ca
    T[..., 0, 2] = st * sa
    T[..., 0, 3] = a * ct
    T[..., 1, 0] = st
    T[..., 1, 1] = ct * ca
    T[..., 1, 2] = -ct * sa
    T[..., 1, 3] = a * st
    T[..., 2, 1] = sa
    T[..., 2, 2] = ca
    T[..., 2, 3] = d
    T[..., 3, 3] = 1.0
    return T


@dataclass(frozen=True)
class Beam:
    """Beam lines in the world: origins `origin` (..., 3) metres and unit directions
    `direction` (..., 3); `d_origin` (..., 3, 2) and `d_direction` (..., 3, 2) their
    derivatives with respect to (pan, tilt)."""

    origin: Array
    direction: Array
    d_origin: Array = field(repr=False)
    d_direction: Array = field(repr=False)


@dataclass(frozen=True)
class SpotJacobian:
    """The 2x2 Jacobian d(spot x, y)/d(pan, tilt) at q, metres per radian.

    `J` (..., 2, 2); `det` (...); `sigma_min` (...) its smallest singular value; `singular`
    (...) True where sigma_min is below the tolerance asked for (beam along the pan axis)."""

    J: Array
    det: Array
    sigma_min: Array
    singular: NDArray[np.bool_]


@dataclass(frozen=True)
class PanTiltProjector:
    """A pan-tilt laser projector on a mount (see the module docstring for the frames).

    `T_world_base` (4, 4); DH parameters per joint: `theta` (2,) zero offsets (rad), `d` (2,),
    `a` (2,) (m), `alpha` (2,) (rad); `beam_origin` (3,) in frame 2 (m); `pan_limits`,
    `tilt_limits` (lower, upper) radians; `max_rate` (rad/s) and `max_acceleration` (rad/s^2)
    per joint; `floor_height` the height (m) of the plane the spot lands on.
    """

    T_world_base: Array
    theta: Array = field(default_factory=lambda: np.zeros(2))
    d: Array = field(default_factory=lambda: np.zeros(2))
    a: Array = field(default_factory=lambda: np.zeros(2))
    alpha: Array = field(default_factory=lambda: np.array([-math.pi / 2, 0.0]))
    beam_origin: Array = field(default_factory=lambda: np.zeros(3))
    pan_limits: tuple[float, float] = (-math.pi, math.pi)
    tilt_limits: tuple[float, float] = (0.0, 1.4)
    max_rate: tuple[float, float] = (3.0, 3.0)
    max_acceleration: tuple[float, float] = (10.0, 10.0)
    floor_height: float = 0.0

    def __post_init__(self) -> None:
        T = as_matrix(self.T_world_base, (4, 4), "T_world_base")
        R = T[:3, :3]
        if np.max(np.abs(R.T @ R - np.eye(3))) > 1e-6 or np.linalg.det(R) <= 0:
            raise InvalidInput("T_world_base's rotation must be orthonormal with det +1")
        if np.max(np.abs(T[3] - [0, 0, 0, 1])) > 1e-12:
            raise InvalidInput("T_world_base must have the last row (0, 0, 0, 1)")
        object.__setattr__(self, "T_world_base", T)
        for name, n in (("theta", 2), ("d", 2), ("a", 2), ("alpha", 2), ("beam_origin", 3)):
            object.__setattr__(self, name, as_matrix(getattr(self, name), (n,), name))
        for name in ("pan_limits", "tilt_limits"):
            lo, hi = (float(v) for v in getattr(self, name))
            if not lo < hi:
                raise InvalidInput(f"{name} must be (lower, upper) with lower < upper")
            object.__setattr__(self, name, (lo, hi))
        for name in ("max_rate", "max_acceleration"):
            v = tuple(float(x) for x in getattr(self, name))
            if len(v) != 2 or not all(math.isfinite(x) and x > 0 for x in v):
                raise InvalidInput(f"{name} must hold two positive numbers (pan, tilt)")
            object.__setattr__(self, name, v)

    @property
    def lower(self) -> Array:
        """Lower joint limits (pan, tilt), radians."""
        return np.array([self.pan_limits[0], self.tilt_limits[0]])

    @property
    def upper(self) -> Array:
        """Upper joint limits (pan, tilt), radians."""
        return np.array([self.pan_limits[1], self.tilt_limits[1]])

    @property
    def is_ideal(self) -> bool:
        """Whether every offset is zero (the closed-form inverse is then exact)."""
        return bool(
            np.all(self.theta == 0)
            and np.all(self.d == 0)
            and np.all(self.a == 0)
            and self.alpha[0] == -math.pi / 2
            and self.alpha[1] == 0
            and np.all(self.beam_origin == 0)
        )

    def with_pose(self, T_world_base: ArrayLike) -> PanTiltProjector:
        """Return a copy mounted at another pose."""
        return replace(self, T_world_base=np.asarray(T_world_base, dtype=np.float64))

    # -- forward kinematics ----------------------------------------------------------------

    def beam(self, q: ArrayLike, *, derivatives: bool = True) -> Beam:
        """Return the beam lines (world) for joint angles q (..., 2) = (pan, tilt), radians,
        with their derivatives (geometric Jacobian of a revolute chain, Spong et al. 4.6;
        empty arrays without `derivatives`)."""
        qa = np.asarray(q, dtype=np.float64)
        if qa.shape[-1:] != (2,) or not np.all(np.isfinite(qa)):
            raise InvalidInput(
                f"q must be finite (pan, tilt) pairs, shape (..., 2); got {qa.shape}"
            )
        A1 = _dh(qa[..., 0] + self.theta[0], self.d[0], self.a[0], self.alpha[0])
        A2 = _dh(qa[..., 1] + self.theta[1], self.d[1], self.a[1], self.alpha[1])
        T1 = self.T_world_base @ A1
        T2 = T1 @ A2
        o = T2[..., :3, :3] @ self.beam_origin + T2[..., :3, 3]
        dvec = -T2[..., :3, 1]
        if not derivatives:
            return Beam(origin=o, direction=dvec, d_origin=np.empty(0), d_direction=np.empty(0))
        z0 = np.broadcast_to(self.T_world_base[:3, 2], o.shape)
        p0 = np.broadcast_to(self.T_world_base[:3, 3], o.shape)
        z1, p1 = T1[..., :3, 2], T1[..., :3, 3]
        d_o = np.stack([np.cross(z0, o - p0), np.cross(z1, o - p1)], -1)
        d_d = np.stack([np.cross(z0, dvec), np.cross(z1, dvec)], -1)
        return Beam(origin=o, direction=dvec, d_origin=d_o, d_direction=d_d)

    def _intersect(self, b: Beam) -> tuple[Array, Array, Array]:
        """Return (points (..., 3), l (...), dz (...)) of beams with the floor plane."""
        dz = b.direction[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = (self.floor_height - b.origin[..., 2]) / dz
        return b.origin + lam[..., None] * b.direction, lam, dz

    def spot(self, q: ArrayLike, *, strict: bool = True) -> Array:
        """Return the floor spots (..., 2) (world x, y, metres) of joint angles q (..., 2).

        With `strict` (default) a beam that does not reach the floor raises BeamAboveHorizon
        (level or upward beam) or BeamMissesFloor (floor behind its origin), naming the first
        such q; otherwise those spots are NaN.
        """
        b = self.beam(q, derivatives=False)
        X, lam, dz = self._intersect(b)
        above = ~(dz <= -_MIN_DESCENT)
        behind = ~above & ~(lam > 0)
        bad = above | behind
        if np.any(bad):
            if strict:
                qa = np.asarray(q, dtype=np.float64).reshape(-1, 2)
                k = int(np.flatnonzero(bad.ravel())[0])
                where = f"q = ({qa[k, 0]:.6g}, {qa[k, 1]:.6g}) rad"
                if above.ravel()[k]:
                    raise BeamAboveHorizon(
                        f"the beam at {where} points level or upwards and never reaches the "
                        "floor; lower the tilt"
                    )
                raise BeamMissesFloor(
                    f"the beam at {where} meets the floor plane behind its origin; check the "
                    "mount pose (is the unit above the floor?)"
                )
            X = np.where(bad[..., None], np.nan, X)
        return X[..., :2]

    def jacobian(self, q: ArrayLike, *, tol: float = 1e-6) -> SpotJacobian:
        """Return d(spot)/dq (..., 2, 2) at q (..., 2), metres per radian, with singularity flags.

        Differentiating X = o + l d with l = (h - o_z) / d_z:
        dX = do + dl d + l dd, dl = -(do_z + l dd_z) / d_z. `tol` is the smallest singular
        value (metres per radian) treated as regular: at the pan singularity (beam along the pan
        axis) the pan column vanishes.
        """
        b = self.beam(q)
        _X, lam, dz = self._intersect(b)
        if np.any(~(dz <= -_MIN_DESCENT)) or np.any(~(lam > 0)):
            self.spot(q)  # raises the precise error
        dlam = -(b.d_origin[..., 2, :] + lam[..., None] * b.d_direction[..., 2, :]) / dz[..., None]
        dX = (
            b.d_origin
            + b.direction[..., :, None] * dlam[..., None, :]
            + lam[..., None, None] * b.d_direction
        )
        J = dX[..., :2, :]
        sv = np.asarray(np.linalg.svd(J, compute_uv=False), dtype=np.float64)
        return SpotJacobian(
            J=J, det=np.linalg.det(J), sigma_min=sv[..., -1], singular=sv[..., -1] < tol
        )

    def joint_rates(
        self, q: ArrayLike, spot_velocity: ArrayLike, *, damping: float = 1e-3
    ) -> Array:
        """Return joint rates (..., 2) rad/s giving the spot velocity (..., 2) m/s at q.

        Solves J qdot = v by damped least squares, qdot = J^T (J J^T + lambda^2 I)^-1 v
        (Nakamura & Hanafusa 1986), lambda = `damping` m/rad: away from the singularity
        (sigma_min >> lambda) it is the exact inverse to O(lambda^2 / sigma_min^2); at the pan
        singularity it returns the least-norm rate instead of an infinite one.
        """
        jac = self.jacobian(q).J
        v = np.asarray(spot_velocity, dtype=np.float64)
        JJt = jac @ np.swapaxes(jac, -1, -2) + damping**2 * np.eye(2)
        y = np.linalg.solve(JJt, v[..., None])
        out: Array = (np.swapaxes(jac, -1, -2) @ y)[..., 0]
        return out

    def spot_velocity(self, q: ArrayLike, qdot: ArrayLike) -> Array:
        """Return spot velocities (..., 2) m/s for joint rates qdot (..., 2) at q."""
        out: Array = (self.jacobian(q).J @ np.asarray(qdot, dtype=np.float64)[..., None])[..., 0]
        return out

    # -- inverse kinematics ----------------------------------------------------------------

    def _closed_form(self, targets: Array, q_ref: Array) -> Array:
        """Return ideal-model joint angles (N, 2) aiming from the beam's mean origin at the
        targets (N, 3), the branch (and pan turn) nearest q_ref (N, 2) within the limits."""
        # The beam origin at the reference angles stands in for the true one; Newton then
        # absorbs the difference (a few centimetres at most for a real unit).
        o = self.beam(q_ref, derivatives=False).origin
        R, t = self.T_world_base[:3, :3], self.T_world_base[:3, 3]
        u = (targets - o) @ R  # in base axes
        u = u / np.linalg.norm(u, axis=-1, keepdims=True)
        tilt = np.arccos(np.clip(u[:, 2], -1.0, 1.0))
        planar = np.hypot(u[:, 0], u[:, 1])
        pan = np.where(planar > SINGULAR_TILT, np.arctan2(u[:, 1], u[:, 0]), q_ref[:, 0])
        del t
        # Each tilt branch with its pan turned to the one nearest q_ref; the pan range is
        # checked after Newton (the offsets move the pan by up to a few degrees there).
        cands = []
        for p, tl in ((pan, tilt), (pan + math.pi, -tilt)):
            p = p - self.theta[0]
            p = q_ref[:, 0] + wrap_angle(p - q_ref[:, 0])
            cands.append(np.stack([p, tl - self.theta[1]], -1))
        C = np.stack(cands, 1)  # (N, 2, 2)
        lo, hi = self.tilt_limits
        margin = 0.2  # rad: the closed form is off by O(offset / range) near the limits
        ok = (C[..., 1] >= lo - margin) & (C[..., 1] <= hi + margin)
        strict = (C[..., 1] >= lo) & (C[..., 1] <= hi)
        # A branch inside the limits always wins over one only within the margin.
        dist = np.sum((C - q_ref[:, None, :]) ** 2, -1) + np.where(strict, 0.0, 1e6)
        dist = np.where(ok, dist, np.inf)
        k = np.argmin(dist, 1)
        best = C[np.arange(len(C)), k]
        best[~np.isfinite(dist[np.arange(len(C)), k])] = np.nan
        return best

    def _solve(
        self, P2: Array, q0: Array, q_ref: Array, tol: float
    ) -> tuple[Array, NDArray[np.bool_]]:
        """Return (q (N, 2), failed (N,)) of Newton's method on spot(q) = P2 from q0, the pan
        turned within its limits nearest q_ref."""
        n = len(P2)
        q = q0.copy()
        bad = np.isnan(q[:, 0])
        for _ in range(_NEWTON_ITERATIONS):
            idx = np.flatnonzero(~bad)
            if len(idx) == 0:
                break
            r = self.spot(q[idx], strict=False) - P2[idx]
            fine = ~np.isnan(r[:, 0])
            bad[idx[~fine]] = True
            idx, r = idx[fine], r[fine]
            if len(idx) == 0 or np.max(np.abs(r)) <= tol:
                break
            jac = self.jacobian(q[idx]).J
            # Damped step: harmless away from the singularity, bounded at it.
            JJt = jac @ np.swapaxes(jac, -1, -2) + 1e-18 * np.eye(2)
            step = (np.swapaxes(jac, -1, -2) @ np.linalg.solve(JJt, r[..., None]))[..., 0]
            q[idx] -= step
        X = self.spot(np.where(bad[:, None], 0.0, q), strict=False)
        err = np.linalg.norm(X - P2, axis=1)
        # The pan is periodic: of the turns q_pan + 2 pi k within the limits, the nearest.
        turns = q[:, :1] + 2 * math.pi * np.array([-1.0, 0.0, 1.0])
        fits = (turns >= self.pan_limits[0] - 1e-9) & (turns <= self.pan_limits[1] + 1e-9)
        gap = np.where(fits, np.abs(turns - q_ref[:, :1]), np.inf)
        pick = np.argmin(gap, 1)
        q[:, 0] = turns[np.arange(n), pick]
        inside = np.isfinite(gap[np.arange(n), pick])
        inside &= (q[:, 1] >= self.tilt_limits[0] - 1e-9) & (q[:, 1] <= self.tilt_limits[1] + 1e-9)
        fail = bad | ~(err <= max(1e3 * tol, 1e-9)) | ~inside
        return q, fail

    def aim(
        self, points: ArrayLike, q_current: ArrayLike | None = None, *, tol: float = 1e-12
    ) -> Array:
        """Return joint angles (N, 2) or (2,) putting the spot on floor points (N, 2) / (2,).

        Closed form for the ideal model (module docstring), on the branch and pan turn nearest
        to `q_current` ((2,) or (N, 2), default (0, mid tilt)) within the joint limits; then
        Newton's method on spot(q) - p = 0 with the full model's Jacobian, until the floor
        residual is below `tol` metres (quadratic convergence: 2-4 steps). Directly below the
        unit (the pan singularity) the pan stays at q_current's. Raises UnreachablePoint naming
        the first point no angles within the limits reach.
        """
        p = np.asarray(points, dtype=np.float64)
        single = p.ndim == 1
        P2 = np.atleast_2d(p)
        if P2.ndim != 2 or P2.shape[1] != 2 or not np.all(np.isfinite(P2)):
            raise InvalidInput(f"points must be finite floor points (N, 2) or (2,); got {p.shape}")
        n = len(P2)
        if q_current is None:
            q_ref = np.tile([0.0, 0.5 * sum(self.tilt_limits)], (n, 1))
        else:
            q_ref = np.broadcast_to(np.asarray(q_current, dtype=np.float64), (n, 2)).copy()
        targets = np.column_stack([P2, np.full(n, self.floor_height)])
        q, fail = self._solve(P2, self._closed_form(targets, q_ref), q_ref, tol)
        if np.any(fail) and not self.is_ideal:
            # Near the pan singularity the offsets move the pan a long way from the ideal
            # closed form: restart those points from the current angles, then from pan seeds
            # a quarter turn apart, keeping the first solution within the limits.
            seeds = [q_ref[fail]] + [
                np.column_stack(
                    [q_ref[fail, 0] + k * math.pi / 2, np.maximum(q_ref[fail, 1], 0.05)]
                )
                for k in range(4)
            ]
            idx = np.flatnonzero(fail)
            for seed in seeds:
                qs, fs = self._solve(P2[idx], seed, q_ref[idx], tol)
                q[idx[~fs]] = qs[~fs]
                fail[idx[~fs]] = False
                idx = idx[fs]
                if len(idx) == 0:
                    break
        if np.any(fail):
            k = int(np.flatnonzero(fail)[0])
            raise UnreachablePoint(
                f"floor point ({P2[k, 0]:.4f}, {P2[k, 1]:.4f}) m is outside the projector's "
                f"reach within pan {self.pan_limits} and tilt {self.tilt_limits} rad; choose a "
                "point the beam can see"
            )
        q = np.clip(q, self.lower, self.upper)
        return q[0] if single else q
