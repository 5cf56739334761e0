"""Path projection: a floor path and a spot speed -> a time-stamped joint trajectory.

The path (a poly-line, optionally with its corners rounded by circular fillets) is sampled
every `ds` metres along its arc length s; every sample is aimed at (PanTiltProjector.aim,
continuing from the previous sample's angles), which gives q(s). The time law s(t) is then the
fastest one within

    |s'| <= spot_speed,   |s''| <= spot_acceleration,   kappa s'^2 <= spot_acceleration,
    |dq_j/ds s'| <= max_rate_j,   |d2q_j/ds2 s'^2 + dq_j/ds s''| <= max_acceleration_j,

found by the forward-backward integration of s'^2 over s (the phase-plane method of Bobrow,
Dubowsky & Gibson 1985; Pham 2014, "A general, fast, and robust implementation of the
time-optimal path parameterization algorithm", sec. II). At a poly-line corner (curvature
infinite) it brings the spot to rest; under the pan singularity (dq/ds large) it slows it
down. The trajectory starts and ends at rest.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_points
from core.errors import InvalidInput
from core.projector._model import PanTiltProjector, UnreachablePoint

Array = NDArray[np.float64]

# Turning angle (rad) at one path sample above which the sample is a corner; a fillet of radius
# r sampled every ds turns by ds / r per sample (0.017 rad for 5 mm on 0.3 m).
_CORNER = 0.1


@dataclass(frozen=True)
class JointTrajectory:
    """A time-stamped projector trajectory sampled every `dt` seconds.

    `t` (K,) s; `q` (K, 2) joint angles rad; `qdot` (K, 2) rad/s; `spot` (K, 2) the planned
    floor spot (world x, y, m); `spot_velocity` (K, 2) m/s; `s` (K,) arc length m;
    `duration` s; `length` m of the path drawn; `turn_rate` (K,) rad/s the rate at which the
    spot's direction of motion turns (zero where it rests).
    """

    t: Array
    q: Array
    qdot: Array
    spot: Array
    spot_velocity: Array = field(repr=False)
    s: Array = field(repr=False)
    duration: float
    length: float
    turn_rate: Array = field(repr=False, default_factory=lambda: np.zeros(0))

    def at(self, time: ArrayLike) -> tuple[Array, Array]:
        """Return (q (..., 2), spot (..., 2)) at the given times by linear interpolation,
        held at the ends."""
        tt = np.asarray(time, dtype=np.float64)
        q = np.stack([np.interp(tt, self.t, self.q[:, j]) for j in range(2)], -1)
        p = np.stack([np.interp(tt, self.t, self.spot[:, j]) for j in range(2)], -1)
        return q, p

    def reference(self, time: ArrayLike) -> tuple[Array, Array, Array]:
        """Return (spot (..., 2), spot velocity (..., 2), turn rate (...)) at the given times:
        the reference the service streams to a robot following the spot (the turn rate is
        that of the spot's direction of motion, rad/s, zero where the spot is at rest)."""
        tt = np.asarray(time, dtype=np.float64)
        p = np.stack([np.interp(tt, self.t, self.spot[:, j]) for j in range(2)], -1)
        v = np.stack([np.interp(tt, self.t, self.spot_velocity[:, j]) for j in range(2)], -1)
        return p, v, np.interp(tt, self.t, self.turn_rate)


def fillet_path(points: ArrayLike, radius: float, *, step: float = 0.01) -> Array:
    """Return the poly-line (M, 2) with every corner replaced by a circular arc of `radius`
    metres tangent to both segments (shrunk where a segment is too short for it), sampled
    every `step` metres along the arcs. radius 0 returns the points unchanged."""
    P = as_points(points, 2, "points", min_count=2)
    if not (math.isfinite(radius) and radius >= 0):
        raise InvalidInput(f"radius must be >= 0 metres, got {radius}")
    keep = np.concatenate([[True], np.linalg.norm(np.diff(P, axis=0), axis=1) > 1e-12])
    P = P[keep]
    if radius == 0 or len(P) < 3:
        return P.copy()
    seg = np.linalg.norm(np.diff(P, axis=0), axis=1)
    out = [P[0]]
    for k in range(1, len(P) - 1):
        a, b, c = P[k - 1], P[k], P[k + 1]
        u1, u2 = (b - a) / seg[k - 1], (c - b) / seg[k]
        turn = math.atan2(u1[0] * u2[1] - u1[1] * u2[0], float(u1 @ u2))
        if abs(turn) < 1e-9:
            out.append(b)
            continue
        # Tangent length r tan(|turn| / 2), at most half of each neighbouring segment.
        tan_half = math.tan(abs(turn) / 2)
        r = min(radius, 0.5 * seg[k - 1] / tan_half, 0.5 * seg[k] / tan_half)
        lt = r * tan_half
        p1 = b - u1 * lt
        normal = np.array([-u1[1], u1[0]]) * math.copysign(1.0, turn)
        centre = p1 + normal * r
        n_arc = max(2, math.ceil(r * abs(turn) / step) + 1)
        ang0 = math.atan2(p1[1] - centre[1], p1[0] - centre[0])
        angs = ang0 + np.linspace(0.0, turn, n_arc)
        out.extend(centre + r * np.column_stack([np.cos(angs), np.sin(angs)]))
    out.append(P[-1])
    return np.asarray(out)


def _resample(P: Array, ds: float) -> tuple[Array, Array, Array]:
    """Return (points (M, 2), s (M,), curvature (M,)) every ~ds metres along the poly-line,
    keeping its vertices (so corners stay sharp)."""
    seg = np.linalg.norm(np.diff(P, axis=0), axis=1)
    pts, s_list = [P[:1]], [np.zeros(1)]
    s0 = 0.0
    for k, L in enumerate(seg):
        n = max(1, math.ceil(L / ds))
        f = np.arange(1, n + 1) / n
        pts.append(P[k] + f[:, None] * (P[k + 1] - P[k]))
        s_list.append(s0 + f * L)
        s0 += L
    X, s = np.vstack(pts), np.concatenate(s_list)
    # Discrete curvature: turning angle at a sample over the mean of its two spacings.
    kappa = np.zeros(len(X))
    if len(X) > 2:
        d1, d2 = X[1:-1] - X[:-2], X[2:] - X[1:-1]
        ang = np.abs(np.arctan2(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0], np.sum(d1 * d2, 1)))
        h = 0.5 * (np.linalg.norm(d1, axis=1) + np.linalg.norm(d2, axis=1))
        # A turn of more than _CORNER rad at one sample is a corner of the poly-line, where
        # the spot must stop (its velocity would jump): infinite curvature.
        kappa[1:-1] = np.where(ang > _CORNER, np.inf, ang / h)
    return X, s, kappa


def _aim_along(projector: PanTiltProjector, X: Array, q0: Array | None) -> Array:
    """Return joint angles (M, 2) along the samples, continuous from q0 (the pan unwrapped)."""
    q = projector.aim(X, q0 if q0 is not None else None)
    # Aim each sample from its predecessor's angles: one batch seeded by the first angle and
    # then the pan made continuous (nearest turn), which is what a sequential aim gives.
    pan = np.unwrap(q[:, 0])
    start = projector.aim(X[0], q0) if q0 is not None else q[0]
    pan += start[0] - pan[0]
    q = np.column_stack([pan, q[:, 1]])
    lo, hi = projector.lower, projector.upper
    if np.any(q[:, 0] < lo[0] - 1e-9) or np.any(q[:, 0] > hi[0] + 1e-9):
        for shift in (-2 * math.pi, 2 * math.pi):
            qs = q[:, 0] + shift
            if np.all(qs >= lo[0] - 1e-9) and np.all(qs <= hi[0] + 1e-9):
                q[:, 0] = qs
                break
        else:
            raise UnreachablePoint(
                "the path winds the pan past its limits "
                f"{projector.pan_limits} rad; split it or turn the unit's pan range"
            )
    return q


def project_path(
    projector: PanTiltProjector,
    path: ArrayLike,
    spot_speed: float,
    *,
    spot_acceleration: float = 0.5,
    corner_radius: float = 0.0,
    q_start: ArrayLike | None = None,
    ds: float = 0.005,
    dt: float = 0.01,
) -> JointTrajectory:
    """Return the joint trajectory drawing `path` (N, 2) (world x, y metres) with the spot.

    spot_speed (m/s) and spot_acceleration (m/s^2, also the bound on the spot's lateral
    acceleration kappa v^2) shape the time law within the projector's `max_rate` and
    `max_acceleration` (module docstring); `corner_radius` (m) rounds the corners with
    `fillet_path` (0: the spot stops at each corner); `q_start` the joint angles to continue
    from (nearest branch). Sampled every `ds` m along the path, output every `dt` s.
    Raises UnreachablePoint (a point outside the reach or limits), InvalidInput.
    """
    for name, v in (("spot_speed", spot_speed), ("spot_acceleration", spot_acceleration)):
        if not (math.isfinite(v) and v > 0):
            raise InvalidInput(f"{name} must be a positive number, got {v}")
    if not (ds > 0 and dt > 0):
        raise InvalidInput("ds and dt must be positive")
    P = fillet_path(path, corner_radius, step=min(ds, 0.01)) if corner_radius > 0 else path
    P = as_points(P, 2, "path", min_count=2)
    # Fillets meeting mid-segment share an end point: drop repeated points.
    P = P[np.concatenate([[True], np.linalg.norm(np.diff(P, axis=0), axis=1) > 1e-9])]
    if len(P) < 2:
        raise InvalidInput("the path must have two distinct points")
    X, s, kappa = _resample(P, ds)
    q0 = None if q_start is None else np.asarray(q_start, dtype=np.float64)
    q = _aim_along(projector, X, q0)
    dq = np.gradient(q, s, axis=0)
    ddq = np.gradient(dq, s, axis=0)
    vmax = np.asarray(projector.max_rate)
    amax = np.asarray(projector.max_acceleration)

    # Velocity cap per sample (squared): speed, joint rates, lateral and joint-curvature terms.
    with np.errstate(divide="ignore"):
        cap = np.full(len(s), spot_speed**2)
        cap = np.minimum(cap, np.min((vmax / np.maximum(np.abs(dq), 1e-12)) ** 2, axis=1))
        cap = np.minimum(cap, spot_acceleration / np.maximum(kappa, 1e-12))
        cap[np.isinf(kappa)] = 0.0
        cap = np.minimum(cap, np.min(0.5 * amax / np.maximum(np.abs(ddq), 1e-12), axis=1))
    cap[0] = cap[-1] = 0.0

    def accel_bounds(k: int, v2: float) -> tuple[float, float]:
        # s'' within [lo, hi] from the spot's and each joint's acceleration limits.
        lo, hi = -spot_acceleration, spot_acceleration
        for j in range(2):
            if abs(dq[k, j]) > 1e-12:
                a1 = (-amax[j] - ddq[k, j] * v2) / dq[k, j]
                a2 = (amax[j] - ddq[k, j] * v2) / dq[k, j]
                lo, hi = max(lo, min(a1, a2)), min(hi, max(a1, a2))
        return lo, hi

    h = np.diff(s)
    v2 = cap.copy()
    for k in range(len(s) - 1):  # forward: accelerate as hard as allowed
        _, hi = accel_bounds(k, v2[k])
        v2[k + 1] = min(v2[k + 1], max(v2[k] + 2 * max(hi, 0.0) * h[k], 0.0))
    for k in range(len(s) - 1, 0, -1):  # backward: brake in time
        lo, _ = accel_bounds(k, v2[k])
        v2[k - 1] = min(v2[k - 1], max(v2[k] - 2 * min(lo, 0.0) * h[k - 1], 0.0))
    sdot = np.sqrt(np.maximum(v2, 0.0))
    vmean = 0.5 * (sdot[1:] + sdot[:-1])
    # Between two samples where the spot must rest (two close corners) it accelerates for
    # half the gap and brakes for the other half: 2 sqrt(h / a).
    with np.errstate(divide="ignore"):
        dt_knots = np.where(vmean > 0, h / vmean, 2.0 * np.sqrt(h / spot_acceleration))
    t_knots = np.concatenate([[0.0], np.cumsum(dt_knots)])
    duration = float(t_knots[-1])
    t = np.append(np.arange(0.0, duration - 0.5 * dt, dt), duration)
    s_t = np.interp(t, t_knots, s)
    sdot_t = np.interp(t, t_knots, sdot)
    q_t = np.column_stack([np.interp(s_t, s, q[:, j]) for j in range(2)])
    dq_t = np.column_stack([np.interp(s_t, s, dq[:, j]) for j in range(2)])
    spot_t = np.column_stack([np.interp(s_t, s, X[:, j]) for j in range(2)])
    tangent = np.gradient(X, s, axis=0)
    tan_t = np.column_stack([np.interp(s_t, s, tangent[:, j]) for j in range(2)])
    tan_t /= np.maximum(np.linalg.norm(tan_t, axis=1, keepdims=True), 1e-12)
    vel = tan_t * sdot_t[:, None]
    heading = np.unwrap(np.arctan2(tan_t[:, 1], tan_t[:, 0]))
    rate = np.gradient(heading, t) if len(t) > 1 else np.zeros(len(t))
    rate = np.where(sdot_t > 1e-6, rate, 0.0)
    return JointTrajectory(
        t=t,
        q=q_t,
        qdot=dq_t * sdot_t[:, None],
        spot=spot_t,
        spot_velocity=vel,
        s=s_t,
        duration=duration,
        length=float(s[-1]),
        turn_rate=rate,
    )
