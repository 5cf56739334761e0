"""Following the projected laser spot: three control laws and the spot tracker they share.

The robot is a unicycle (x, y, theta) with forward speed v and turn rate omega; spec 03 treats
it as a planar P-P-R manipulator whose joint rates obey the nonholonomic constraint
-sin(theta) dx + cos(theta) dy = 0. The point P = (x, y) + L (cos theta, sin theta) a distance
L ahead of the axle is fully actuated:

    dP/dt = B(theta) [v, omega]^T,   B = [[cos theta, -L sin theta], [sin theta, L cos theta]],
    det B = L,   B^-1 = [[cos theta, sin theta], [-sin theta / L, cos theta / L]]

(Siciliano et al., "Robotics: Modelling, Planning and Control", sec. 11.6.2, input-output
linearisation). Every law drives P onto the spot. Everything is expressed in the robot's
odometry frame: the camera measures the spot in the robot frame at capture time t_c, the
odometry pose at t_c puts it in the odometry frame (this compensates the robot's own motion
during the camera's latency exactly), and the odometry's slow drift cancels between the robot
and the spot, both being measured from it.

Saturation: |v| <= v_max and |omega| <= omega_max are imposed by scaling the command vector
(its direction kept), never by clipping one component (which would bend dP/dt).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import InvalidInput
from core.geometry.rotations import wrap_angle

Array = NDArray[np.float64]


def _rot(theta: float) -> Array:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


def control_point(pose: ArrayLike, lookahead: float) -> Array:
    """Return P (2,) = (x, y) + L (cos theta, sin theta) for a pose (x, y, theta)."""
    x, y, th = (float(v) for v in np.asarray(pose, dtype=np.float64))
    return np.array([x + lookahead * math.cos(th), y + lookahead * math.sin(th)])


def point_to_unicycle(u: ArrayLike, theta: float, lookahead: float) -> Array:
    """Return [v, omega] = B(theta)^-1 u for a desired velocity u (2,) of the point P."""
    c, s = math.cos(theta), math.sin(theta)
    ux, uy = (float(x) for x in np.asarray(u, dtype=np.float64))
    return np.array([c * ux + s * uy, (-s * ux + c * uy) / lookahead])


def saturate(cmd: Array, v_max: float, omega_max: float) -> tuple[Array, bool]:
    """Return (the command scaled into |v| <= v_max, |omega| <= omega_max, whether scaled)."""
    scale = max(abs(cmd[0]) / v_max, abs(cmd[1]) / omega_max, 1.0)
    return cmd / scale, scale > 1.0


@dataclass(frozen=True)
class Limits:
    """Command limits of the base: v_max (m/s), omega_max (rad/s)."""

    v_max: float = 0.5
    omega_max: float = 1.5


class TrackState(StrEnum):
    """What the follower is doing: following the spot, stopping after losing it, searching."""

    TRACKING = "tracking"
    STOPPING = "stopping"
    SEARCHING = "searching"


@dataclass
class SpotTracker:
    """The spot seen from the robot, kept in the odometry frame.

    `add(t_capture, spot_robot, odom_at_capture)` records one measurement (robot-frame spot
    (2,) m, odometry pose (x, y, theta) at the capture time); `velocity()` is the least-squares
    slope of the positions over the last `window` seconds (m/s); `lost(t)` says that no spot
    came for `lost_after` seconds.
    """

    window: float = 0.4
    lost_after: float = 0.4
    times: deque[float] = field(default_factory=lambda: deque(maxlen=64))
    points: deque[Array] = field(default_factory=lambda: deque(maxlen=64))

    def add(self, t_capture: float, spot_robot: ArrayLike, odom: ArrayLike) -> Array:
        """Record a measurement; return the spot in the odometry frame (2,)."""
        o = np.asarray(odom, dtype=np.float64)
        s = o[:2] + _rot(float(o[2])) @ np.asarray(spot_robot, dtype=np.float64)
        self.times.append(float(t_capture))
        self.points.append(s)
        return s

    @property
    def last(self) -> tuple[float, Array] | None:
        """(capture time, odometry-frame spot) of the newest measurement, or None."""
        if not self.times:
            return None
        return self.times[-1], self.points[-1]

    def velocity(self) -> Array:
        """Return the spot's velocity (2,) m/s fitted over the last `window` seconds."""
        if len(self.times) < 2:
            return np.zeros(2)
        t = np.asarray(self.times)
        keep = t >= t[-1] - self.window
        if keep.sum() < 2:
            return np.zeros(2)
        t = t[keep]
        P = np.asarray(self.points)[keep]
        tc = t - t.mean()
        den = float(tc @ tc)
        if den <= 0:
            return np.zeros(2)
        out: Array = tc @ (P - P.mean(0)) / den
        return out

    def lost(self, t: float) -> bool:
        """Whether no measurement has come for `lost_after` seconds (or none ever)."""
        return not self.times or t - self.times[-1] > self.lost_after


@dataclass(frozen=True)
class Reference:
    """What the service streams about the spot it draws: `velocity` (2,) m/s in the world frame
    (the projector's commanded trajectory) and the turn rate of its direction (rad/s)."""

    velocity: Array
    turn_rate: float = 0.0


class SpotFollower:
    """Base of the three laws: the shared tracker, lost-spot handling and saturation.

    `command(t, odom, reference)` returns [v, omega] for the current odometry pose
    (x, y, theta); `observe(t_capture, spot_robot, odom_at_capture)` feeds a measurement when
    the camera's frame arrives. Lost spot (no measurement for `tracker.lost_after` s): stop
    (zero command for 0.5 s; the base's acceleration limits bring it to rest), then search by
    turning in place towards the last spot's bearing at `search_rate` rad/s, and resume as soon
    as a spot arrives. The service holds the spot still meanwhile (see core.sim's
    path-following scenario).
    """

    name = "follower"

    def __init__(
        self,
        lookahead: float = 0.6,
        limits: Limits | None = None,
        *,
        search_rate: float = 0.4,
        tracker: SpotTracker | None = None,
    ) -> None:
        if not (math.isfinite(lookahead) and lookahead > 0):
            raise InvalidInput(f"lookahead L must be positive metres, got {lookahead}")
        self.L = float(lookahead)
        self.limits = limits or Limits()
        self.search_rate = search_rate
        self.tracker = tracker or SpotTracker()
        self.state = TrackState.TRACKING
        self.lost_events = 0
        self._lost_since = 0.0
        self._t_last = None  # type: float | None

    def observe(self, t_capture: float, spot_robot: ArrayLike, odom: ArrayLike) -> None:
        """Feed one spot measurement (robot frame, m) captured at t_capture."""
        self.tracker.add(t_capture, spot_robot, odom)
        self.state = TrackState.TRACKING

    def predicted_spot(self, t: float, velocity: Array) -> Array:
        """Return the spot (2,) (odometry frame) now, the last measurement moved on by
        `velocity` over its age (the camera latency plus the time since the frame)."""
        last = self.tracker.last
        assert last is not None
        tc, s = last
        out: Array = s + velocity * (t - tc)
        return out

    def command(self, t: float, odom: ArrayLike, reference: Reference | None = None) -> Array:
        """Return [v (m/s), omega (rad/s)] for the current odometry pose (x, y, theta)."""
        o = np.asarray(odom, dtype=np.float64)
        dt = 0.0 if self._t_last is None else t - self._t_last
        self._t_last = t
        if self.tracker.last is None:
            return np.zeros(2)  # acquiring: nothing seen yet, nothing lost
        if self.tracker.lost(t):
            if self.state == TrackState.TRACKING:
                self.state = TrackState.STOPPING
                self.lost_events += 1
                self._lost_since = t
                self._on_lost()
            if self.state == TrackState.STOPPING and t - self._lost_since > 0.5:
                self.state = TrackState.SEARCHING
            if self.state == TrackState.STOPPING:
                return np.zeros(2)
            _, s = self.tracker.last
            bearing = math.atan2(s[1] - o[1], s[0] - o[0]) - o[2]
            turn = math.copysign(self.search_rate, wrap_angle(bearing))
            return np.array([0.0, turn])
        cmd, integrate = self._law(t, dt, o, reference)
        out, scaled = saturate(cmd, self.limits.v_max, self.limits.omega_max)
        if integrate is not None and not scaled and dt > 0:
            integrate(dt)
        return out

    def _on_lost(self) -> None:
        """Hook: what a law forgets when the spot is lost."""

    def _law(
        self, t: float, dt: float, odom: Array, reference: Reference | None
    ) -> tuple[Array, _Integrator | None]:
        raise NotImplementedError


class _Integrator:
    """A deferred integration step (applied only when the command was not saturated)."""

    def __init__(self, state: Array, rate: Array, bound: float) -> None:
        self.state, self.rate, self.bound = state, rate, bound

    def __call__(self, dt: float) -> None:
        self.state += self.rate * dt
        n = float(np.linalg.norm(self.state))
        if n > self.bound:
            self.state *= self.bound / n


class ProportionalLaw(SpotFollower):
    """The baseline: P goes straight for the last seen spot, u = B^-1 k (s - P).

    No model of the spot's motion, so a spot moving at constant speed V is followed with the
    steady lag V / k (10 cm at 0.3 m/s for the default k = 3 /s); its measurement is used as it
    comes, so the measurement's age (latency plus on average half a frame) adds V times it.
    """

    name = "proportional"

    def __init__(self, lookahead: float = 0.6, limits: Limits | None = None, *, k: float = 3.0):
        super().__init__(lookahead, limits)
        self.k = k

    def _law(
        self, t: float, dt: float, odom: Array, reference: Reference | None
    ) -> tuple[Array, _Integrator | None]:
        last = self.tracker.last
        assert last is not None
        e = last[1] - control_point(odom, self.L)
        return point_to_unicycle(self.k * e, float(odom[2]), self.L), None


class AdaptiveLaw(SpotFollower):
    """Adaptive compensation: the spot's velocity is unknown and estimated on line.

    With e = s - P (odometry frame) and the estimate v^ of the spot's velocity,

        u = v^ + K e,   [v, omega] = B^-1 u,   dv^/dt = Gamma e.

    Lyapunov argument (Slotine & Li, "Applied Nonlinear Control", sec. 8.2). For a spot at
    constant velocity V, de/dt = V - u = v~ - K e with v~ = V - v^, and dv~/dt = -Gamma e.
    V_L = e^T e / 2 + v~^T v~ / (2 Gamma) has dV_L/dt = e^T v~ - e^T K e - v~^T e = -K |e|^2
    <= 0, so e and v~ are bounded; de/dt is bounded, so by Barbalat's lemma e -> 0: the
    steady-state error on a straight segment at constant speed vanishes, with no knowledge of
    the speed. On a curve V changes at rate |dV/dt| = V^2 kappa and the error stays bounded,
    of order V^2 kappa / (K omega_n) with omega_n = sqrt(Gamma) the adaptation's natural rate.

    Gains: K = 8 /s, Gamma = 12 /s^2. The error obeys e'' + K e' + Gamma e = dV/dt, so on a
    curve of curvature kappa at speed V it settles near V^2 kappa / Gamma (4 mm for the
    0.05 m/s^2 the twin's spot turns with), with natural rate omega_n = sqrt(Gamma) = 3.5 rad/s
    and damping K / (2 omega_n) = 1.15. On a straight stretch what is left is the wheel slip
    the odometry does not see, a random walk in the robot's position that the loop corrects
    at its bandwidth K: the steady error falls as K grows. Gamma is bounded by the base: with
    Gamma = 16 or more, a start a few centimetres off the spot drives the turn rate into its
    acceleration limit and the loop settles into a limit cycle (heading swinging by 0.4 rad),
    seen on the twin with K from 6 to 12. Chosen on the twin's 10 m tour (seeds 20-39) and a
    1 m leg started 11 cm off (seeds 1-40, no cycle); measured on the tour's seeds 100-159:
    the former K = 3, Gamma = 9 left a steady error of 4.5 mm median and up to 8.4 mm, these
    gains 3.4 mm and up to 4.5 mm (RMS over the tour 7.8 -> 7.2 mm median, the curves' share).
    Latency: the measurement (age a) is moved on by v^ a before use. Saturation and anti-windup:
    when |v| or |omega| would exceed its limit the command is scaled down and the adaptation
    frozen for that step (conditional integration), and |v^| is bounded by v_max, so a long
    saturation (a lost spot, a sharp corner) cannot wind the
    estimate up; losing the spot resets v^ to zero.
    """

    name = "adaptive"

    def __init__(
        self,
        lookahead: float = 0.6,
        limits: Limits | None = None,
        *,
        K: float = 8.0,
        Gamma: float = 12.0,
    ):
        super().__init__(lookahead, limits)
        self.K, self.Gamma = K, Gamma
        self.v_hat = np.zeros(2)

    def _on_lost(self) -> None:
        self.v_hat[:] = 0.0

    def _law(
        self, t: float, dt: float, odom: Array, reference: Reference | None
    ) -> tuple[Array, _Integrator | None]:
        s = self.predicted_spot(t, self.v_hat)
        e = s - control_point(odom, self.L)
        u = self.v_hat + self.K * e
        step = _Integrator(self.v_hat, self.Gamma * e, self.limits.v_max)
        return point_to_unicycle(u, float(odom[2]), self.L), step


class StateFeedbackLaw(SpotFollower):
    """Nonlinear state-error feedback (Kanayama, Kimura, Miyazaki & Noguchi, ICRA 1990).

    The reference is a virtual unicycle whose point P rides on the spot: its heading theta_r
    obeys dtheta_r/dt = omega_r with [v_r, omega_r] = B(theta_r)^-1 V_s for the spot's
    commanded velocity V_s (the service knows it), and its axle is at p_r = s - L (cos
    theta_r, sin theta_r). With the tracking error in the robot frame

        [e_x, e_y] = R(theta)^T (p_r - p),   e_theta = theta_r - theta,

    the law is v = v_r cos e_theta + k_x e_x, omega = omega_r + v_r (k_y e_y + k_theta sin
    e_theta). Convergence (Kanayama et al. 1990): the error obeys
    de_x/dt = omega e_y - v + v_r cos e_theta, de_y/dt = -omega e_x + v_r sin e_theta,
    de_theta/dt = omega_r - omega. With V_L = (e_x^2 + e_y^2) / 2 + (1 - cos e_theta) / k_y,
    dV_L/dt = -k_x e_x^2 - v_r k_theta sin^2(e_theta) / k_y <= 0 for v_r >= 0 and positive
    gains, so the error is bounded; when v_r stays positive (the spot keeps moving forward),
    Barbalat's lemma gives e_x, sin e_theta -> 0 and then e_y -> 0. When the robot's pose
    matches the virtual unicycle's, its P is on the spot, so P's error goes to zero too.

    Measured quantities: s is the latest spot moved on by the reference velocity over the
    measurement's age (latency compensation); V_s is the commanded velocity rotated from the
    world into the odometry frame by the frame's drift, estimated as the low-passed angle
    between the spot track's velocity and the commanded one (over ~1 s). Gains: k_x = 3 /s
    and, for the linearised lateral dynamics e_y'' + v_r k_theta e_y' + v_r^2 k_y e_y = 0,
    k_y = 16 /m^2 and k_theta = 10 /m: omega_n = 1.2 rad/s at v_r = 0.3 m/s, damping 1.25.
    The wheels' heading slip turns the odometry frame, so the heading the spot asks for in it
    wanders faster than the drift estimate follows; a stiff heading loop chases that wander
    into lateral error. On the twin's 10 m tour (chosen on seeds 20-39, checked on 100-159)
    the former k_y = 100, k_theta = 20 (omega_n = 3 rad/s) gave an RMS error of 7.5 mm median
    and up to 11.4 mm; these gains 3.8 mm and up to 5.6 mm, with half the largest error.
    """

    name = "state_feedback"

    def __init__(
        self,
        lookahead: float = 0.6,
        limits: Limits | None = None,
        *,
        k_x: float = 3.0,
        k_y: float = 16.0,
        k_theta: float = 10.0,
        drift_gain: float = 1.0,
    ):
        super().__init__(lookahead, limits)
        self.k_x, self.k_y, self.k_theta = k_x, k_y, k_theta
        self.drift_gain = drift_gain
        self.theta_r: float | None = None
        self.drift = 0.0

    def _on_lost(self) -> None:
        self.theta_r = None

    def _law(
        self, t: float, dt: float, odom: Array, reference: Reference | None
    ) -> tuple[Array, _Integrator | None]:
        if reference is None:
            raise InvalidInput("the state-feedback law needs the spot's reference velocity")
        th = float(odom[2])
        if self.theta_r is None:
            self.theta_r = th
        v_world = np.asarray(reference.velocity, dtype=np.float64)
        speed = float(np.linalg.norm(v_world))
        track = self.tracker.velocity()
        if speed > 0.05 and abs(reference.turn_rate) < 0.05 and np.linalg.norm(track) > 0.05:
            ang = wrap_angle(math.atan2(track[1], track[0]) - math.atan2(v_world[1], v_world[0]))
            # The odometry's heading drifts slowly: a low-pass over ~1 / drift_gain seconds,
            # on straight stretches only (on a curve the fitted track lags the command).
            self.drift += min(self.drift_gain * dt, 1.0) * wrap_angle(ang - self.drift)
        V = _rot(self.drift) @ v_world
        s = self.predicted_spot(t, V)
        v_r, w_r = point_to_unicycle(V, self.theta_r, self.L)
        p_r = s - self.L * np.array([math.cos(self.theta_r), math.sin(self.theta_r)])
        e = _rot(th).T @ (p_r - np.asarray(odom[:2]))
        e_th = wrap_angle(self.theta_r - th)
        v = v_r * math.cos(e_th) + self.k_x * e[0]
        w = w_r + v_r * (self.k_y * e[1] + self.k_theta * math.sin(e_th))
        # The virtual unicycle moves on whatever the robot does (it is the reference).
        self.theta_r = wrap_angle(self.theta_r + w_r * dt)
        return np.array([v, w]), None
