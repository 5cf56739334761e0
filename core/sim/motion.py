"""Motion in the digital twin: the robot base, its odometry, a scripted patrol and walkers.

The base is a unicycle (x, y, yaw) driven by commanded forward speed v (m/s) and turn rate
omega (rad/s). Commands are clamped to the speed limits and their change per step to the
acceleration limits; the wheels then execute the clamped motion exactly, which is what the
odometry integrates, while the true motion departs from it by wheel-slip noise (a random walk
per metre and per radian travelled, Thrun, Burgard & Fox, Probabilistic Robotics, sec. 5.4).
So the odometry is a sensor of its own whose drift has the statistics configured in
`SlipNoise`. Time is an integer step count times dt, so runs are exactly reproducible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import InvalidInput
from core.geometry.rotations import wrap_angle
from core.sim.crowd import crowd_of, script_positions
from core.sim.scene import MotionLimits, Robot, Scene, SlipNoise, Walker

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Pose2D:
    """A pose on the floor: position (x, y) metres, heading yaw radians about world Z."""

    x: float
    y: float
    yaw: float

    def as_array(self) -> Array:
        """Return (x, y, yaw), shape (3,)."""
        return np.array([self.x, self.y, self.yaw])


@dataclass(frozen=True)
class BaseState:
    """The base after a step: `time` s, true `pose`, `odometry` pose (what the wheels report),
    the executed speed `v` (m/s) and turn rate `omega` (rad/s)."""

    time: float
    pose: Pose2D
    odometry: Pose2D
    v: float
    omega: float


@dataclass(frozen=True)
class WorldState:
    """What moves in a scene at one instant: the robot's true pose (None: no robot) and each
    walker's floor position (x, y) metres, in the scene's order of `people`."""

    time: float
    robot: Pose2D | None
    people: tuple[tuple[float, float], ...] = ()


class SimClock:
    """A deterministic clock: time = steps * dt exactly (no accumulated rounding)."""

    def __init__(self, dt: float) -> None:
        if not (math.isfinite(dt) and dt > 0):
            raise InvalidInput(f"dt must be a positive number of seconds, got {dt}")
        self.dt = float(dt)
        self.steps = 0

    @property
    def time(self) -> float:
        """Return the current time in seconds."""
        return self.steps * self.dt

    def tick(self) -> float:
        """Advance one step; return the new time in seconds."""
        self.steps += 1
        return self.time


def _advance(x: float, y: float, yaw: float, ds: float, dl: float, dyaw: float) -> Pose2D:
    # Second-order (midpoint heading) integration of a body-frame displacement (ds forward,
    # dl to the left) with rotation dyaw; exact for straight lines, O(dyaw^2 ds) for arcs.
    h = yaw + 0.5 * dyaw
    c, s = math.cos(h), math.sin(h)
    return Pose2D(x + ds * c - dl * s, y + ds * s + dl * c, wrap_angle(yaw + dyaw))


class UnicycleBase:
    """A simulated robot base with limits, wheel slip and odometry.

    `step(v_cmd, omega_cmd)` advances the clock by dt and returns the BaseState. The noise
    comes from `rng` (a numpy Generator or a seed), so the same seed gives the same run.
    """

    def __init__(
        self,
        limits: MotionLimits,
        slip: SlipNoise,
        start: Pose2D,
        *,
        dt: float = 0.05,
        rng: np.random.Generator | int | None = None,
    ) -> None:
        self.limits = limits
        self.slip = slip
        self.clock = SimClock(dt)
        self._rng = np.random.default_rng(rng)
        self._pose = start
        self._odom = start
        self._v = 0.0
        self._omega = 0.0

    @classmethod
    def from_robot(
        cls, robot: Robot, *, dt: float = 0.05, rng: np.random.Generator | int | None = None
    ) -> UnicycleBase:
        """Return a base with the robot's limits, slip noise and start pose."""
        return cls(robot.limits, robot.slip, Pose2D(*robot.start), dt=dt, rng=rng)

    @property
    def state(self) -> BaseState:
        """Return the current state."""
        return BaseState(self.clock.time, self._pose, self._odom, self._v, self._omega)

    def step(self, v_cmd: float, omega_cmd: float) -> BaseState:
        """Execute (v_cmd m/s, omega_cmd rad/s) for one dt within the limits; return the state."""
        if not (math.isfinite(v_cmd) and math.isfinite(omega_cmd)):
            raise InvalidInput(f"commands must be finite, got v={v_cmd}, omega={omega_cmd}")
        lim, dt = self.limits, self.clock.dt
        v_t = min(max(v_cmd, -lim.max_speed), lim.max_speed)
        w_t = min(max(omega_cmd, -lim.max_turn_rate), lim.max_turn_rate)
        dv_max, dw_max = lim.max_acceleration * dt, lim.max_angular_acceleration * dt
        self._v += min(max(v_t - self._v, -dv_max), dv_max)
        self._omega += min(max(w_t - self._omega, -dw_max), dw_max)

        ds, dyaw = self._v * dt, self._omega * dt
        n = self._rng.standard_normal(3)
        sl = self.slip
        root_d = math.sqrt(abs(ds))
        e_s = sl.distance_per_sqrt_m * root_d * n[0]
        e_l = sl.lateral_per_sqrt_m * root_d * n[1]
        e_h = math.sqrt(sl.heading_per_sqrt_m**2 * abs(ds) + sl.heading_per_sqrt_rad**2 * abs(dyaw))
        p, o = self._pose, self._odom
        self._pose = _advance(p.x, p.y, p.yaw, ds + e_s, e_l, dyaw + e_h * n[2])
        self._odom = _advance(o.x, o.y, o.yaw, ds, 0.0, dyaw)
        self.clock.tick()
        return self.state


class Patrol:
    """A scripted patrol: drive to each waypoint in turn (and around again if `loop`).

    The command turns towards the next waypoint (turn rate gain * heading error) and drives at
    up to the speed limit, slowing while the heading error is large and near the last waypoint;
    a waypoint counts as reached within `tolerance` metres.
    """

    def __init__(
        self,
        waypoints: ArrayLike,
        limits: MotionLimits,
        *,
        loop: bool = True,
        tolerance: float = 0.1,
        gain: float = 2.0,
    ) -> None:
        w = np.asarray(waypoints, dtype=np.float64)
        if w.ndim != 2 or w.shape[1] != 2 or len(w) < 1 or not np.all(np.isfinite(w)):
            raise InvalidInput(f"waypoints must be finite, shape (N >= 1, 2), got {w.shape}")
        self.waypoints = w
        self.limits = limits
        self.loop = loop
        self.tolerance = tolerance
        self.gain = gain
        self.index = 0
        self.done = False

    def command(self, pose: Pose2D) -> tuple[float, float]:
        """Return (v m/s, omega rad/s) towards the current waypoint from `pose`."""
        if self.done:
            return 0.0, 0.0
        for _ in range(len(self.waypoints) + 1):
            target = self.waypoints[self.index]
            dx, dy = target[0] - pose.x, target[1] - pose.y
            dist = math.hypot(dx, dy)
            if dist >= self.tolerance:
                break
            self.index += 1
            if self.index == len(self.waypoints):
                if not self.loop:
                    self.done = True
                    return 0.0, 0.0
                self.index = 0
        else:
            return 0.0, 0.0  # every waypoint is within tolerance of where the robot stands
        err = wrap_angle(math.atan2(dy, dx) - pose.yaw)
        omega = self.gain * err
        v = self.limits.max_speed * max(0.0, math.cos(err)) ** 2
        if not self.loop and self.index == len(self.waypoints) - 1:
            # Brake in time: v <= sqrt(2 a d) stops within the remaining distance.
            v = min(v, math.sqrt(2.0 * self.limits.max_acceleration * dist))
        return v, omega


@dataclass(frozen=True)
class Trajectory:
    """A simulated drive sampled every step: `time` (N,) s, true `pose` (N, 3) and `odometry`
    (N, 3) as (x, y, yaw), executed `v` (N,) m/s and `omega` (N,) rad/s. Row 0 is the start."""

    time: Array
    pose: Array
    odometry: Array
    v: Array
    omega: Array


def simulate_patrol(
    robot: Robot,
    duration: float,
    *,
    dt: float = 0.05,
    rng: np.random.Generator | int | None = None,
    waypoints: ArrayLike | None = None,
    loop: bool = True,
) -> Trajectory:
    """Return the trajectory of `robot` patrolling its waypoints (or `waypoints`) for
    `duration` seconds from its start pose, with slip noise drawn from `rng`."""
    wp = robot.patrol if waypoints is None else waypoints
    if len(np.asarray(wp)) == 0:
        raise InvalidInput(f"robot {robot.name!r} has no patrol waypoints; pass waypoints")
    base = UnicycleBase.from_robot(robot, dt=dt, rng=rng)
    patrol = Patrol(wp, robot.limits, loop=loop)
    n = round(duration / dt)
    states = [base.state]
    for _ in range(n):
        states.append(base.step(*patrol.command(states[-1].pose)))
    return Trajectory(
        time=np.array([s.time for s in states]),
        pose=np.array([s.pose.as_array() for s in states]),
        odometry=np.array([s.odometry.as_array() for s in states]),
        v=np.array([s.v for s in states]),
        omega=np.array([s.omega for s in states]),
    )


def walker_positions(walker: Walker, times: ArrayLike) -> Array:
    """Return the walker's floor positions (N, 2) metres at `times` (N,) seconds when it walks
    alone (its script: `core.sim.crowd.script_positions`). With others, ask their `Crowd`."""
    return script_positions(walker, times)


def world_state(scene: Scene, time: float, robot: Pose2D | None = None) -> WorldState:
    """Return the scene's WorldState at `time` s: walkers on their scripts, giving way to each
    other (`core.sim.crowd`); the robot at `robot` or, if None, at its start pose (None when
    the scene has no robot)."""
    pose = robot
    if pose is None and scene.robot is not None:
        pose = Pose2D(*scene.robot.start)
    people = tuple((float(x), float(y)) for x, y in crowd_of(scene.people).positions([time])[0])
    return WorldState(time=float(time), robot=pose, people=people)
