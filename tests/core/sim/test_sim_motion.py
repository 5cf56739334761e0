"""Robot base limits, odometry drift statistics, the patrol, walkers and the clock."""

from __future__ import annotations

import math

import numpy as np
import pytest

from core.errors import InvalidInput
from core.sim import (
    Patrol,
    Pose2D,
    SimClock,
    UnicycleBase,
    default_scene,
    simulate_patrol,
    walker_positions,
    world_state,
)
from core.sim.scene import MotionLimits, SlipNoise, Walker

LIMITS = MotionLimits(
    max_speed=0.5, max_turn_rate=1.5, max_acceleration=0.8, max_angular_acceleration=3.0
)


def test_limits_are_respected_under_wild_commands() -> None:
    dt = 0.05
    base = UnicycleBase(LIMITS, SlipNoise(), Pose2D(0, 0, 0), dt=dt, rng=0)
    rng = np.random.default_rng(1)
    v, w = [0.0], [0.0]
    for _ in range(2000):
        s = base.step(float(rng.normal(0, 3)), float(rng.normal(0, 10)))
        v.append(s.v)
        w.append(s.omega)
    v_, w_ = np.array(v), np.array(w)
    eps = 1e-12
    assert np.abs(v_).max() <= LIMITS.max_speed + eps
    assert np.abs(w_).max() <= LIMITS.max_turn_rate + eps
    assert np.abs(np.diff(v_)).max() <= LIMITS.max_acceleration * dt + eps
    assert np.abs(np.diff(w_)).max() <= LIMITS.max_angular_acceleration * dt + eps
    # The limits are reached, not just respected (the test could not fail otherwise).
    assert np.abs(v_).max() == pytest.approx(LIMITS.max_speed)
    assert np.abs(np.diff(v_)).max() == pytest.approx(LIMITS.max_acceleration * dt)


def test_acceleration_ramp_is_exact_without_slip() -> None:
    no_slip = SlipNoise(**dict.fromkeys(SlipNoise.model_fields, 0.0))
    base = UnicycleBase(LIMITS, no_slip, Pose2D(0, 0, 0), dt=0.1, rng=0)
    states = [base.step(1.0, 0.0) for _ in range(20)]
    # v ramps at 0.8 m/s^2 to 0.5 m/s (reached after 0.625 s), then cruises.
    assert [s.v for s in states[:7]] == pytest.approx([0.08, 0.16, 0.24, 0.32, 0.4, 0.48, 0.5])
    x_expected = sum(s.v for s in states) * 0.1
    assert states[-1].pose.x == pytest.approx(x_expected, abs=1e-12)
    assert states[-1].pose == states[-1].odometry  # no slip: odometry is exact
    assert states[-1].time == pytest.approx(2.0, abs=0)


def test_odometry_drift_has_the_configured_statistics() -> None:
    """Straight 4 m drives: the odometry's final error against the truth has along-track std
    distance_per_sqrt_m sqrt(d) and heading std heading_per_sqrt_m sqrt(d).

    400 runs: the sample std of 400 normal draws is within 3 x 1/sqrt(800) = 11 % of the true
    one with probability 0.997; 12 % is used.
    """
    slip = SlipNoise(
        distance_per_sqrt_m=0.02,
        lateral_per_sqrt_m=0.0,
        heading_per_sqrt_m=0.015,
        heading_per_sqrt_rad=0.0,
    )
    limits = MotionLimits(max_speed=0.5, max_acceleration=100.0)
    dt, n_steps, runs = 0.1, 80, 400  # 80 steps at 0.5 m/s: d = 4 m
    along, heading = [], []
    rng = np.random.default_rng(5)
    for _ in range(runs):
        base = UnicycleBase(limits, slip, Pose2D(0, 0, 0), dt=dt, rng=rng)
        for _ in range(n_steps):
            s = base.step(0.5, 0.0)
        along.append(s.pose.x - s.odometry.x)
        heading.append(s.pose.yaw - s.odometry.yaw)
    d = 0.5 * dt * n_steps
    assert s.odometry.x == pytest.approx(d)
    assert np.std(along) == pytest.approx(slip.distance_per_sqrt_m * math.sqrt(d), rel=0.12)
    assert np.std(heading) == pytest.approx(slip.heading_per_sqrt_m * math.sqrt(d), rel=0.12)
    assert abs(np.mean(along)) < 3 * slip.distance_per_sqrt_m * math.sqrt(d / runs)


def test_turning_in_place_drifts_by_heading_per_sqrt_rad() -> None:
    slip = SlipNoise(
        distance_per_sqrt_m=0.0,
        lateral_per_sqrt_m=0.0,
        heading_per_sqrt_m=0.0,
        heading_per_sqrt_rad=0.03,
    )
    limits = MotionLimits(max_turn_rate=1.0, max_angular_acceleration=100.0)
    rng = np.random.default_rng(9)
    err = []
    for _ in range(400):
        base = UnicycleBase(limits, slip, Pose2D(0, 0, 0), dt=0.1, rng=rng)
        for _ in range(20):  # 2 rad
            s = base.step(0.0, 1.0)
        err.append(s.pose.yaw - s.odometry.yaw)
        assert s.pose.x == 0.0 and s.pose.y == 0.0
    assert np.std(err) == pytest.approx(0.03 * math.sqrt(2.0), rel=0.12)


def test_patrol_visits_its_waypoints_and_is_reproducible() -> None:
    robot = default_scene().robot
    assert robot is not None
    a = simulate_patrol(robot, 60.0, dt=0.05, rng=3)
    b = simulate_patrol(robot, 60.0, dt=0.05, rng=3)
    c = simulate_patrol(robot, 60.0, dt=0.05, rng=4)
    assert np.array_equal(a.pose, b.pose) and not np.array_equal(a.pose, c.pose)
    assert a.time[-1] == pytest.approx(60.0)
    # Every waypoint is passed within the controller's 0.1 m tolerance (by the odometry the
    # controller sees; the true path differs by the drift).
    wp = np.array(robot.patrol)
    d = np.linalg.norm(a.pose[:, None, :2] - wp[None], axis=2).min(0)
    assert d.max() < 0.1 + 0.05  # tolerance + a step's travel (0.5 m/s x 0.05 s) + drift
    assert np.abs(a.v).max() <= robot.limits.max_speed + 1e-12


def test_patrol_stops_at_the_end_without_loop() -> None:
    p = Patrol([[1.0, 0.0]], LIMITS, loop=False)
    base = UnicycleBase(LIMITS, SlipNoise(), Pose2D(0, 0, 0), dt=0.05, rng=0)
    s = base.state
    for _ in range(200):
        s = base.step(*p.command(s.pose))
    assert p.done and s.v == pytest.approx(0.0, abs=1e-12)
    assert math.hypot(s.pose.x - 1.0, s.pose.y) < 0.12


def test_walker_walks_at_its_speed_back_and_forth() -> None:
    w = Walker(name="w", waypoints=[(0.0, 0.0), (3.0, 0.0), (3.0, 4.0)], speed=1.0)
    t = np.arange(0.0, 20.0, 0.01)
    p = walker_positions(w, t)
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    assert step.max() == pytest.approx(0.01, abs=1e-9)  # constant speed, never faster
    at = walker_positions(w, [0.0, 3.0, 7.0, 10.0, 14.0])
    np.testing.assert_allclose(at, [[0, 0], [3, 0], [3, 4], [3, 1], [0, 0]], atol=1e-12)
    loop = Walker(name="l", waypoints=[(0.0, 0.0), (3.0, 0.0), (3.0, 4.0)], speed=1.0, loop=True)
    # Around the closed polyline of length 3 + 4 + 5 = 12 m.
    at = walker_positions(loop, [12.0, 14.5, 21.5])
    np.testing.assert_allclose(at, [[0, 0], [2.5, 0], [1.5, 2.0]], atol=1e-12)


def test_world_state_and_clock() -> None:
    scene = default_scene()
    st = world_state(scene, 2.5)
    assert st.robot == Pose2D(*scene.robot.start)  # type: ignore[union-attr]
    assert st.people == (tuple(walker_positions(scene.people[0], [2.5])[0]),)
    clock = SimClock(0.1)
    for _ in range(1000):
        clock.tick()
    assert clock.time == 100.0  # steps x dt, no accumulated rounding
    with pytest.raises(InvalidInput):
        SimClock(0.0)
    base = UnicycleBase(LIMITS, SlipNoise(), Pose2D(0, 0, 0))
    with pytest.raises(InvalidInput):
        base.step(float("nan"), 0.0)


def test_patrol_standing_on_its_only_waypoint_holds_still() -> None:
    p = Patrol([[0.0, 0.0]], LIMITS, loop=True)
    assert p.command(Pose2D(0.02, 0.0, 0.0)) == (0.0, 0.0)
    with pytest.raises(InvalidInput):
        Patrol([[0.0, float("nan")]], LIMITS)
