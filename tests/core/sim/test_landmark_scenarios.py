"""The landmark scenarios on small studies: `landmark-pose` (a calibrated head camera, one
obliquity bin, both kinds), the head's kinematics and the polar law, `landmark-reading` and
`landmark-survey`."""

from __future__ import annotations

import json

import numpy as np
import pytest

from core.errors import InvalidInput
from core.geometry.poses import planar_pose
from core.landmarks.ambiguity import PoseHypothesis
from core.sim.head_camera import (
    calibrate_scene_head_camera,
    reading_standoff,
    robot_head_pose,
)
from core.sim.head_robot import (
    HeadRobot,
    TrackedLandmark,
    polar_command,
)
from core.sim.installation import installed_cameras
from core.sim.scenarios.landmark_pose import landmark_pose
from core.sim.scenarios.landmark_reading import landmark_reading
from core.sim.scenarios.landmark_survey import _se2_exp, _se2_log, landmark_survey
from core.sim.scene import default_scene, load_scene


def test_landmark_pose_small_study() -> None:
    r = landmark_pose(None, 3, views_per_bin=2, bins=((40.0, 50.0),), calibration_views=6)
    d = r.to_dict()
    json.dumps(d)  # JSON-ready
    assert d["scenario"] == "landmark-pose" and d["seed"] == 3
    # Zhang calibration from six rendered chessboard views: focal length within 0.5 % and
    # principal point within 3 px of the truth (0.05 px corner noise, 640x480).
    assert abs(d["calibration_focal_error_pct"]) < 0.5
    assert d["calibration_principal_point_error_px"] < 3.0
    assert [b["kind"] for b in d["bins"]] == ["object", "signpost"]
    for b in d["bins"]:
        assert b["views"] == 2
        # 0.5-5 m at 40-50 deg: everything within each kind's limit is located; the object
        # mark beyond 3 m may be missed (not required), so at least one of two is found.
        assert b["located_pct"] >= 50.0
        assert b["position_error_pct_median"] < 1.0  # spec 04: < 1 % of distance
        assert b["normal_error_deg_median"] < 2.0  # spec 04: < 2 deg at 45 deg
        if b["decode_views"]:
            assert b["decoded_pct"] >= b["zxing_raw_pct"]
        # A frame's pose has no alternative: always decided. No decided pose flips here
        # (at most 1 % of decided poses may, core.landmarks.ambiguity).
        if b["kind"] == "object":
            assert b["undecided_pct"] == 0.0
        assert b["decided_flips_pct"] in (0.0, None)
    with pytest.raises(InvalidInput):
        landmark_pose(None, 0, views_per_bin=0)


def test_head_pose_axes() -> None:
    """At pan = tilt = 0 the head looks along the robot's +x with image up = +z; pan turns it
    to the left, tilt down; the optical centre sits at the mount's position."""
    head = default_scene().robot.head_camera  # type: ignore[union-attr]
    assert head is not None
    T = robot_head_pose(head, 0.0, 0.0)
    np.testing.assert_allclose(T[:3, 2], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(T[:3, 1], [0, 0, -1], atol=1e-12)  # image y down = world -z
    np.testing.assert_allclose(T[:3, 3], head.position)
    np.testing.assert_allclose(robot_head_pose(head, np.pi / 2, 0.0)[:3, 2], [0, 1, 0], atol=1e-12)
    look = robot_head_pose(head, 0.0, 0.3)[:3, 2]
    np.testing.assert_allclose(look, [np.cos(0.3), 0, -np.sin(0.3)], atol=1e-12)


@pytest.mark.parametrize(
    "start", [(-1.0, 0.5, 0.0), (-0.6, -1.2, 2.0), (1.0, 1.0, np.pi), (0.3, -0.2, -1.5)]
)
def test_polar_law_reaches_the_goal_pose(start: tuple[float, float, float]) -> None:
    """The polar pose-regulation law on an ideal unicycle: to within 2 cm and 2 deg of the goal
    (0, 0, 0) in 40 s from ahead, behind and beside it (Astolfi's law converges exponentially;
    with K_RHO = 0.4 the distance falls by e every 2.5 s)."""
    x, y, th = start
    dt = 0.01
    for _ in range(4000):
        v, w, _ = polar_command(np.array([x, y, th]), np.zeros(3))
        x += v * np.cos(th) * dt
        y += v * np.sin(th) * dt
        th = (th + w * dt + np.pi) % (2 * np.pi) - np.pi
    assert np.hypot(x, y) < 0.02
    assert abs(th) < np.radians(2.0)


def test_landmark_reading_few_trials() -> None:
    """PBVS reading from three random starts in the default home (the CLI runs 100)."""
    r = landmark_reading(None, 5, trials=3, calibration_views=6)
    d = r.to_dict()
    json.dumps(d)
    assert d["scenario"] == "landmark-reading" and len(d["runs"]) == 3
    # Spec 04: >= 95 % within 60 s; three trials can show one failure at most at that rate
    # only with probability 0.7 %, so two of three is the bound this size can hold.
    assert sum(t["read"] for t in d["runs"]) >= 2
    # Every landmark of the home is drawn: a read counts only on the trial's own landmark.
    wrong = [t for t in d["runs"] if t["read_landmark"] not in (None, t["landmark"])]
    assert d["wrong_landmark_reads"] == len(wrong) and not any(t["read"] for t in wrong)
    for t in d["runs"]:
        if t["read"]:
            assert 0 < t["time_to_read"] <= 60.0 and t["read_landmark"] == t["landmark"]
            assert not t["collided"]
    with pytest.raises(InvalidInput):
        landmark_reading(None, 0, trials=0)


def test_landmark_survey_small_home() -> None:
    """The survey on the default home keeping two kitchen landmarks (an object mark and a
    signpost) and one stop: both read and mapped, no false or duplicate entry."""
    home = default_scene().model_dump(mode="python")
    home["landmarks"] = [m for m in home["landmarks"] if m["name"] in ("kettle", "signpost_22")]
    home["robot"]["start"] = (5.2, 1.45, 0.0)
    scene = load_scene(home)
    # The same ceiling cameras as the default home's (only landmarks were taken down): its
    # installed calibration.
    cams = installed_cameras(default_scene())
    r = landmark_survey(scene, 1, tour=((5.2, 1.45),), calibration_views=6, cameras=cams)
    d = r.to_dict()
    json.dumps(d)
    assert (d["objects_present"], d["objects_seen"], d["objects_found"]) == (1, 1, 1)
    assert (d["places_present"], d["places_seen"], d["places_found"]) == (1, 1, 1)
    assert d["false_entries"] == 0 and d["duplicate_entries"] == 0
    assert not d["seen_not_read"]
    assert d["completed"] and not d["collided"]
    # The ceiling cameras saw the marker while the base drove to its reading poses, and their
    # fixes entered the pose estimate.
    assert d["ceiling"]["cameras"] == 5 and d["ceiling"]["frames"] > 0 and d["ceiling"]["fixes"] > 0
    # Read from under 1 m (pose error ~1 % of distance) on odometry that drove a few metres
    # from the known start (slip 1 cm per sqrt(m)): a few centimetres.
    assert d["position_error_mean_m"] < 0.05
    # One room has a place: no route to the others, reported, not raised.
    assert all(rt["places"] is None and rt["error"] for rt in d["routes"])


def test_reading_plans_around_the_dining_table() -> None:
    """The fridge's mark read from behind the dining table's corner: the straight way to the
    reading pose crosses the table (plus the base's radius), so the base follows a route
    planned on the floor plan to a point on the mark's estimated normal and PBVS drives it in
    from there: read within 60 s, the true base never touching the table."""
    scene = default_scene()
    rng = np.random.default_rng(4)
    K, dist, _ = calibrate_scene_head_camera(scene, rng, 6)
    marks = HeadRobot(scene, K, dist, rng=rng).landmarks
    k = next(i for i, m in enumerate(marks) if m.name == "fridge")
    # Every landmark of the home is drawn; the robot must read the fridge's.
    robot = HeadRobot(scene, K, dist, start=np.array([5.4, 2.6, -0.5]), rng=rng)
    m = marks[k].T_world_mark
    # The reading pose from the true pose (scoring the set-up only): out of sight of the start.
    d_h = reading_standoff("object", K[0, 0], robot.head.position[2] - m[2, 3])
    reading = m[:2, 3] + m[:2, 2] * (d_h + robot.head.position[0])
    assert not robot.routes.sees(np.array([5.4, 2.6]), reading)
    out = robot.read(None, 60.0)
    assert out.read and out.detection is not None and out.detection.text == marks[k].text
    assert not robot.collided
    assert robot.approach is not None and len(robot.approach.route) > 2  # a bend round the table


def test_drift_correction_is_spread_along_the_path() -> None:
    """A planar correction exp(lam log D): lam = 0 leaves the pose, lam = 1 applies D whole,
    and two halves make the whole (a one-parameter subgroup)."""
    D = planar_pose((0.3, -0.2, 0.25))
    x = _se2_log(D)
    np.testing.assert_allclose(_se2_exp(x), D, atol=1e-12)
    np.testing.assert_allclose(_se2_exp(0 * x), np.eye(4), atol=1e-12)
    half = _se2_exp(0.5 * x)
    np.testing.assert_allclose(half @ half, D, atol=1e-12)


def test_a_reading_pose_with_nothing_free_on_its_normal_takes_the_nearest_free_pose() -> None:
    """A reading pose 6 cm from the dining table's end whose normal runs back along the table
    (every pose on it within the table's margin): the approach stands the base on the nearest
    free pose instead, with a route there. Without it the polar law drove the base alone from
    across the room, which touched the TV stand and the bookshelf in 4 of 5 surveys."""
    scene = default_scene()
    rng = np.random.default_rng(2)
    K, dist, _ = calibrate_scene_head_camera(scene, rng, 6)
    robot = HeadRobot(scene, K, dist, start=np.array([5.2, 1.0, 0.0]), rng=rng)
    goal = np.array([6.96, 2.15, 0.0])  # odometry frame = world at the start
    assert not any(robot.routes.free(goal[:2] - [s, 0.0]) for s in np.arange(0.0, 0.51, 0.05))
    ap = robot._plan_approach(goal)
    assert ap is not None
    stand = goal[:2] + ap.offset
    assert robot.routes.free(stand) and np.linalg.norm(ap.offset) <= 0.5
    np.testing.assert_allclose(ap.route[-1], stand, atol=0.08)  # the route leads there


def _facing(n: list[float]) -> np.ndarray:
    z = np.asarray(n, float) / np.linalg.norm(n)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = [3.0, 0.0, 1.2]
    return T


def test_an_undecided_track_approaches_between_its_two_poses() -> None:
    # A signpost seen from the origin along +x: its two poses' normals mirrored about the line
    # of sight (-x), 40 deg either side. Undecided (0.7 / 0.3), the approach is along their
    # weighted mean, between the two and off both; decided, along the chosen one.
    a, b = _facing([-np.cos(0.7), np.sin(0.7), 0.0]), _facing([-np.cos(0.7), -np.sin(0.7), 0.0])
    cov = np.eye(6) * 1e-4
    undecided = TrackedLandmark(
        a, "signpost", 0.0, (PoseHypothesis(a, cov, 0.7), PoseHypothesis(b, cov, 0.3))
    )
    assert not undecided.decided
    n = undecided.normal()
    n = n / np.linalg.norm(n)
    angle = lambda u, v: float(np.degrees(np.arccos(np.clip(u @ v, -1, 1))))  # noqa: E731
    assert angle(n, a[:3, 2]) > 10.0 and angle(n, b[:3, 2]) > 10.0
    # The weighted mean of the two unit normals: (0.7 - 0.3) sin 0.7 across the line of sight.
    expected = np.degrees(np.arctan2(0.4 * np.sin(0.7), np.cos(0.7)))
    assert angle(n, np.array([-1.0, 0.0, 0.0])) == pytest.approx(expected, abs=1e-9)
    decided = TrackedLandmark(
        a, "signpost", 0.0, (PoseHypothesis(a, cov, 0.999), PoseHypothesis(b, cov, 0.001))
    )
    assert decided.decided and np.allclose(decided.normal(), a[:3, 2])
    # A landmark known only from a map (no view yet) keeps its pose.
    assert TrackedLandmark(a, "signpost", 0.0).decided
