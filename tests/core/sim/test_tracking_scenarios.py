"""Tracking scenarios: spec 08's unsynchronised cameras (the acceptance bars, shortened in
length only), walkers' pauses, and the MOT scoring against an independent count."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from core.errors import InvalidInput
from core.localization.tracking import TrackerConfig
from core.sim import crowd
from core.sim.crowd import crowd_around, robot_poses
from core.sim.motion import simulate_patrol, walker_positions
from core.sim.scenarios import multi_target_tracking as ts
from core.sim.scene import Walker
from core.sim.tracking_score import TrackLog, score_tracks

# Seeds 0 and 3 chose the tracker's settings; this one was not looked at before (more seeds,
# ten minutes each, come from `intspace sim run tracking-async --json`).
SEEDS = (21,)


@pytest.mark.parametrize("seed", SEEDS)
def test_tracking_async_meets_spec_08(seed):
    minutes = 2.0
    r = ts.tracking_async(seed=seed, minutes=minutes)
    assert r.conditions == {
        "rate_hz": 10.0,
        "noise_px": 0.7,
        "miss": 0.05,
        "clutter_per_frame": 0.3,
        "height_m": 1.0,
        "people_overlap_s": 0.0,  # nobody walks through anybody
    }
    assert r.idf1 >= 0.95 and r.mota >= 0.95, r
    # At most one switch per walker per ten minutes.
    assert r.id_switches <= max(1, int(r.targets * minutes / 10.0)), r
    # Spec 08: never more live targets than bodies (measured: 3 live at most for 3 walkers).
    assert r.max_live_targets <= r.targets, r
    # The tracker knows the cameras only as their network calibration placed them. In that
    # calibrated frame the walkers are within spec 08's 5 cm; against the twin the frame's own
    # rigid error (the calibration's gauge: its heading is tied to the robot's first straight
    # leg, bound ~0.6 deg) adds to it, and no more than that.
    assert r.person_rmse_in_frame_m <= 0.05, r
    assert r.person_rmse_m <= np.hypot(0.05, r.frame_error_m), r


def test_without_the_life_cycle_clutter_would_count():
    # The scoring can fail: a tracker that confirms every birth at once keeps clutter tracks
    # alive, which shows as false positives and more live targets than bodies.
    cfg = TrackerConfig(confirm_hits=1)
    r = ts.tracking_async(seed=SEEDS[0], minutes=0.5, config=cfg)
    assert r.max_live_targets > r.targets and r.false_positives > 0


def test_walkers_pause_at_their_waypoints():
    w = Walker(name="w", waypoints=[(0.0, 0.0), (2.0, 0.0)], speed=1.0, pauses=[1.0, 3.0])
    t = np.array([0.5, 2.0, 4.5, 5.5, 6.0, 7.0, 7.5])
    xy = walker_positions(w, t)
    # 2 s out, 3 s standing at the end, 2 s back, 1 s standing at the start, round again.
    expected = [0.5, 2.0, 2.0, 1.5, 1.0, 0.0, 0.0]
    np.testing.assert_allclose(xy[:, 0], expected, atol=1e-12)
    with pytest.raises(ValueError, match="one value per waypoint"):
        Walker(name="w", waypoints=[(0.0, 0.0), (2.0, 0.0)], pauses=[1.0])


def test_score_counts_a_swap_and_a_false_track():
    # Two bodies, two tracks that swap halfway, and a third track far from both: motmetrics
    # must see two switches... per body one, and the far track's points as false positives.
    t = np.arange(0.0, 2.0, 0.1)
    a = np.column_stack([t, np.zeros_like(t)])
    b = np.column_stack([t, np.full_like(t, 2.0)])
    truth = np.stack([a, b], axis=1)
    half = t < 1.0
    log = TrackLog()
    log.points[1] = [(ti, *(a[i] if half[i] else b[i])) for i, ti in enumerate(t)]
    log.points[2] = [(ti, *(b[i] if half[i] else a[i])) for i, ti in enumerate(t)]
    log.points[3] = [(ti, 10.0, 10.0) for ti in t]
    for k in (1, 2, 3):
        log.confirmed_at[k] = 0.0
    score = score_tracks(t, truth, log)
    assert score.id_switches == 2
    assert score.false_positives == t.size and score.misses == 0
    assert score.max_live_targets == 3 and score.rmse_m == 0.0
    assert score.mota == pytest.approx(1.0 - (2 + t.size) / (2 * t.size))


def test_scenario_needs_a_robot_with_a_marker():
    scene = ts.tracking_scene()
    bare = scene.model_copy(update={"robot": None})
    with pytest.raises(InvalidInput, match="robot"):
        ts.tracking(bare, minutes=0.01)


def _segment_distance(p, a, b):
    ab, ap = b - a, p - a
    s = np.clip(ap @ ab / max(ab @ ab, 1e-12), 0.0, 1.0)
    return float(np.linalg.norm(ap - s * ab))


def test_nobody_stands_where_another_walks():
    # People give way to each other (core.sim.crowd) by waiting or stepping back along their
    # own path. A person who stands or turns round within reach of another's path could not
    # get out of the way there and would be walked through, which no camera of a real home
    # sees. Paths may cross; standing and turning places stay clear by the crowd's comfort
    # distance (surface to surface). The robot is not held to this: it stops for a person
    # standing in its way until they walk on (the next test shows nobody is driven through).
    scene = ts.tracking_scene()
    for w in scene.people:
        ends = [0, len(w.waypoints) - 1] if not w.loop else []
        stands = [
            np.asarray(p)
            for i, (p, pause) in enumerate(zip(w.waypoints, w.pauses, strict=True))
            if pause or i in ends
        ]
        assert stands, w.name
        for other in scene.people:
            if other is w:
                continue
            clear = w.radius + other.radius + crowd.COMFORT_M
            path = np.asarray(other.waypoints, dtype=np.float64)
            legs = list(itertools.pairwise(path)) + ([(path[-1], path[0])] if other.loop else [])
            for p in stands:
                gap = min(_segment_distance(p, a, b) for a, b in legs)
                assert gap >= clear, (w.name, p.tolist(), other.name, gap)


def test_the_scenario_people_and_robot_cross_without_touching():
    # Alone, the walker's and the resident's scripts bring them within a few centimetres of
    # each other where their paths cross, and the robot's patrol crosses both; as a crowd,
    # nobody comes closer than two body radii plus the contact margin, the robot (right of way)
    # keeps to its drive, and the walk never falls back on passing through anybody.
    scene = ts.tracking_scene()
    assert scene.robot is not None
    t = np.arange(0.0, 300.0, 0.1)
    drive = np.asarray(simulate_patrol(scene.robot, 301.0, dt=0.05, rng=4).pose)
    walk = crowd_around(scene, drive)
    xy = walk.positions(t)  # the robot, then the walkers
    r = np.array([scene.robot.base_radius] + [w.radius for w in scene.people])
    for i, j in itertools.combinations(range(len(r)), 2):
        d = np.linalg.norm(xy[:, i] - xy[:, j], axis=1)
        assert d.min() >= r[i] + r[j] + crowd.CONTACT_M - 1e-9, (i, j, d.min())
    alone = np.stack([walker_positions(w, t) for w in scene.people], axis=1)
    d_alone = np.linalg.norm(alone[:, 0] - alone[:, 1], axis=1)
    assert d_alone.min() < r[1] + r[2]  # the scripts alone do collide: the test can fail
    assert walk.overlap_s == 0.0
    robot = robot_poses(walk, drive, t)
    np.testing.assert_allclose(robot[:, :2], xy[:, 0], rtol=0, atol=1e-12)
