"""The three spot-following laws on an ideal unicycle: convergence, lag, lost-spot handling."""

from __future__ import annotations

import math

import numpy as np
import pytest

from core.navigation import (
    AdaptiveLaw,
    Limits,
    ProportionalLaw,
    Reference,
    StateFeedbackLaw,
    TrackState,
    control_point,
)

V = np.array([0.3, 0.0])  # the spot's velocity, m/s, along world x
DT = 0.02


def _follow(law, seconds: float, *, latency: float = 0.1, rate: float = 15.0) -> np.ndarray:
    """Drive an exact unicycle (no limits beyond the law's own saturation) after a spot moving
    at V from (0.6, 0.05); the robot starts at rest at the origin facing +x. The camera sees
    the spot exactly (robot frame) every 1/rate s, delivered `latency` s later. Returns the
    error |P - spot| per step."""
    pose = np.zeros(3)
    pending: list[tuple[float, float, np.ndarray, np.ndarray]] = []
    errs = []
    next_cap = 0.0
    for k in range(round(seconds / DT)):
        t = k * DT
        spot = np.array([0.6, 0.05]) + V * t
        if t + 1e-9 >= next_cap:
            next_cap += 1.0 / rate
            c, s = math.cos(pose[2]), math.sin(pose[2])
            rel = np.array([[c, s], [-s, c]]) @ (spot - pose[:2])
            pending.append((t + latency, t, rel, pose.copy()))
        while pending and pending[0][0] <= t + 1e-9:
            _, tc, z, od = pending.pop(0)
            law.observe(tc, z, od)
        errs.append(np.linalg.norm(control_point(pose, law.L) - spot))
        v, w = law.command(t, pose, Reference(velocity=V, turn_rate=0.0))
        # Exact integration of the unicycle over the step (arc of constant v, w).
        th = pose[2]
        if abs(w) > 1e-12:
            pose[0] += v / w * (math.sin(th + w * DT) - math.sin(th))
            pose[1] += -v / w * (math.cos(th + w * DT) - math.cos(th))
        else:
            pose[0] += v * DT * math.cos(th)
            pose[1] += v * DT * math.sin(th)
        pose[2] = th + w * DT
    return np.asarray(errs)


def test_adaptive_law_removes_the_steady_error_of_a_constant_velocity_spot() -> None:
    e = _follow(AdaptiveLaw(0.6, Limits(0.6, 2.0)), 20.0)
    # Lyapunov + Barbalat: e -> 0 for an unknown constant velocity (docstring); after 15 s
    # (45 time constants of the error dynamics) only the discretisation is left.
    assert np.max(e[-250:]) < 1e-4
    assert e[0] > 0.04  # it started off the spot: the check is not vacuous


def test_state_feedback_converges_with_the_reference_velocity() -> None:
    e = _follow(StateFeedbackLaw(0.6, Limits(0.6, 2.0)), 20.0)
    assert np.max(e[-250:]) < 1e-3
    assert e[0] > 0.04


def test_proportional_law_lags_by_speed_over_gain_plus_latency() -> None:
    k = 3.0
    e = _follow(ProportionalLaw(0.6, Limits(0.6, 2.0), k=k), 20.0)
    # It steers P to the last measurement, which is V (latency + half a frame on average)
    # behind the spot, and lags that by V / k: about 0.3/3 + 0.3 * (0.1 + 1/30) = 0.14 m.
    expected = 0.3 / k + 0.3 * (0.1 + 0.5 / 15.0)
    assert np.mean(e[-250:]) == pytest.approx(expected, rel=0.1)


def test_a_lost_spot_stops_then_searches_then_resumes() -> None:
    law = AdaptiveLaw(0.6, Limits(0.5, 1.5))
    pose = np.zeros(3)
    law.observe(0.0, [0.6, 0.3], pose)
    assert law.command(0.05, pose).tolist() != [0.0, 0.0]
    assert law.state == TrackState.TRACKING
    # Nothing for longer than tracker.lost_after (0.4 s): stop.
    assert law.command(0.5, pose).tolist() == [0.0, 0.0]
    assert law.state == TrackState.STOPPING and law.lost_events == 1
    # Still nothing 0.5 s later: turn in place towards the last bearing (to the left here).
    v, w = law.command(1.1, pose)
    assert law.state == TrackState.SEARCHING and v == 0.0 and w > 0
    law.observe(1.15, [0.6, 0.0], pose)
    law.command(1.2, pose)
    assert law.state == TrackState.TRACKING and law.lost_events == 1


def test_commands_respect_the_limits_by_scaling() -> None:
    law = ProportionalLaw(0.6, Limits(0.5, 1.5), k=10.0)
    law.observe(0.0, [3.0, 2.0], np.zeros(3))
    v, w = law.command(0.01, np.zeros(3))
    assert abs(v) <= 0.5 + 1e-12 and abs(w) <= 1.5 + 1e-12
    # Scaled, not clipped: the direction of P's velocity is kept.
    u = np.array([v, 0.6 * w])  # P's velocity at theta = 0 is (v, L w)
    target = np.array([3.0, 2.0]) - [0.6, 0.0]
    assert np.dot(u, target) / (np.linalg.norm(u) * np.linalg.norm(target)) > 1 - 1e-12
