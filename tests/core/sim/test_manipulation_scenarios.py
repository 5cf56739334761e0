"""The hand-eye scenario: views from the eye-in-hand camera, rendered and detected or
projected, calibrated by every method against the twin's truth."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from core.errors import InvalidInput
from core.geometry.camera import project_points
from core.geometry.rotations import matrix_to_rotvec
from core.manipulation import (
    METHODS,
    default_arm,
    default_manipulator,
    invert_pose,
    pose_error,
)
from core.sim import Renderer, default_scene
from core.sim.eye_in_hand import EYE_DIST, EYE_K, eye_camera_intrinsics, hand_eye_views
from core.sim.fetch import GRASP_PHASES, JOINT_RATE, grasp_episode
from core.sim.fetch_placement import fetch_problem
from core.sim.gripper import GRIPPER_OPEN, T_MARK_GRASP, close_gripper, pre_grasp_pose
from core.sim.intrinsics import RenderedCalibration
from core.sim.mark_eye import MarkEye
from core.sim.marked_box import BOX_SIZE, MARK_POINTS
from core.sim.scenarios.manipulation import grasp, hand_eye


@cache
def _intrinsics() -> RenderedCalibration:
    """The eye-in-hand camera's own calibration (rendered chessboard views), made once."""
    return eye_camera_intrinsics(np.random.default_rng(0))


def test_eye_camera_is_calibrated_from_its_own_views() -> None:
    cal = _intrinsics()
    # Zhang on 12 rendered views at ~0.05 px corner noise: the focal length within 0.2 % and
    # the principal point within 1 px of the true lens (scoring only); measured 0.03 % / 0.3 px.
    assert cal.views == 12 and cal.rms < 0.1
    assert abs(cal.K[0, 0] / EYE_K[0, 0] - 1.0) < 2e-3
    assert np.linalg.norm(cal.K[:2, 2] - EYE_K[:2, 2]) < 1.0
    assert not np.allclose(cal.K, EYE_K, rtol=0, atol=1e-6)  # estimated, not copied


def test_views_are_reachable_and_consistent() -> None:
    # The true lens given as the calibration, so the board poses' only error is PnP precision.
    exact = RenderedCalibration(EYE_K, EYE_DIST, 0.0, 0)
    v = hand_eye_views(np.random.default_rng(0), views=5, sigma_px=0.0, intrinsics=exact)
    assert np.all(default_arm().within_limits(v.q))
    # Noise-free pixels: each view's estimated board pose is the true one (to PnP precision),
    # so E_i X C_i is the board's true pose for every view.
    W = v.T_base_ee @ v.true_X @ v.T_cam_target
    for Wi in W:
        dp, dr = pose_error(Wi, v.true_T_base_target)
        assert dp < 1e-9 and dr < 1e-9
    # The views after the first (as many as leave 3 general ones, at most 3) are pure
    # translations of it: no rotation between them, 4-7 cm apart.
    assert v.translations == 2
    E = v.T_base_ee
    for Ei in E[1 : 1 + v.translations]:
        np.testing.assert_allclose(Ei[:3, :3], E[0][:3, :3], atol=1e-9)
        assert 0.04 <= np.linalg.norm(Ei[:3, 3] - E[0][:3, 3]) <= 0.07
    with pytest.raises(InvalidInput):
        hand_eye_views(np.random.default_rng(0), views=2)


def test_projected_scenario_meets_spec_with_refinement() -> None:
    r = hand_eye(seed=1, rendered=False)
    d = r.to_dict()
    assert d["scenario"] == "hand-eye" and d["source"] == "projected" and d["views"] == 15
    assert {m["method"] for m in d["methods"]} == set(METHODS)
    assert d["intrinsics_from"].startswith("Zhang calibration") and d["focal_error_pct"] < 0.2
    # 0.5 px per axis measured against the truth (525 noise samples: +-7 % at 2 sigma).
    assert d["measured_sigma_px"] == pytest.approx(0.5, rel=0.1)
    # Spec 05: <= 0.1 deg and <= 1 mm (bench/bench_hand_eye.py: median 0.04 deg, 0.16 mm over
    # 100 trials); one trial may be above the median, so twice that median is the bound here.
    assert r.refined.rotation_error_deg < 0.1 and r.refined.translation_error_mm < 1.0
    best_linear = min(m.translation_error_mm for m in r.methods)
    assert r.refined.translation_error_mm < best_linear


def test_rendered_views_detect_the_board() -> None:
    # supersample=1 keeps the test quick; the scenario renders with the default 2.
    renderer = Renderer(default_scene(), supersample=1)
    v = hand_eye_views(
        np.random.default_rng(2),
        views=3,
        sigma_px=0.0,
        rendered=True,
        renderer=renderer,
        intrinsics=_intrinsics(),
        translations=0,
    )
    assert v.source == "rendered"
    # Corners detected in the rendered images (sensor noise, blur, lens distortion) against
    # the true projections: measured ~0.03 px per axis; 0.2 px bounds a detector gone wrong.
    C_true = invert_pose(v.T_base_ee @ v.true_X) @ v.true_T_base_target
    for uv, c in zip(v.image_points, C_true, strict=True):
        truth = project_points(
            v.object_points, matrix_to_rotvec(c[:3, :3]), c[:3, 3], EYE_K, EYE_DIST
        )
        assert np.sqrt(np.mean((uv - truth.points) ** 2)) < 0.2
    r = v.calibrate("park", refine=True)
    dp, dr = pose_error(r.X, v.true_X)
    # Three views at ~0.03 px: well inside spec 05's 1 mm / 0.1 deg.
    assert dp < 1e-3 and dr < np.radians(0.1)


def test_grasp_scenario_keys_and_accuracy() -> None:
    # Every image rendered by the twin, its mark detected: the scenario as it runs in full,
    # shortened to 4 episodes.
    r = grasp(seed=3, episodes=4)
    d = r.to_dict()
    for key in ("episodes", "success_rate", "position_error_m", "rotation_error_deg"):
        assert key in d
    assert d["episodes"] == 4 and len(d["per_episode"]) == 4
    assert d["source"] == "rendered" and d["frames"] == sum(e.frames for e in r.per_episode)
    # Its inputs said as they are: the eye-in-hand camera's own calibration, and the marked box
    # it grasps (a printed chessboard, not spec 04's object mark).
    assert d["intrinsics_from"].startswith("Zhang calibration") and d["focal_error_pct"] < 0.2
    assert "chessboard" in d["target"] and "not spec 04's object mark" in d["target"]
    # Spec 05: >= 95 % over 100 episodes (`intspace sim run grasp` measures it); on 4 episodes
    # at least 3 must succeed, each within 5 mm and 2 degrees by definition of success.
    assert r.success_rate >= 0.75
    assert r.position_error_m < 5e-3 and r.rotation_error_deg < 2.0
    for e in r.per_episode:
        if e.success:
            assert e.position_error_mm < 5.0 and e.rotation_error_deg < 2.0 and e.switches >= 1
            # The fingers stopped on the box's 115 mm (up to 1 mm more if it sits turned by
            # the 2 degrees a success allows).
            assert 115.0 <= e.gripper_opening_mm < 117.0
            assert e.frames > 5


def test_eye_in_hand_images_show_the_mark_where_it_is() -> None:
    # The rendered look at the box: the mark's corners detected within a fraction of a pixel
    # of their true projections, in the order of MARK_POINTS.
    rng = np.random.default_rng(4)
    renderer = Renderer(default_scene(), supersample=1)
    T_mark = np.eye(4)
    c, s = np.cos(0.7), np.sin(0.7)
    T_mark[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T_mark[:3, 3] = [6.2, 1.66, 0.85]
    X = default_manipulator().T_ee_camera
    T_cam = T_mark @ _PRE_GRASP @ X
    px = MarkEye(T_mark, 0.0, rng, renderer).observe(T_cam)
    assert px is not None
    C = invert_pose(T_cam) @ T_mark
    truth = project_points(MARK_POINTS, matrix_to_rotvec(C[:3, :3]), C[:3, 3], EYE_K, EYE_DIST)
    assert np.sqrt(np.mean((px - truth.points) ** 2)) < 0.2
    # Looking away (the camera turned half round about its optical axis's normal): no mark.
    away = T_cam.copy()
    away[:3, :3] = away[:3, :3] @ np.diag([1.0, -1.0, -1.0])
    assert MarkEye(T_mark, 0.0, rng, renderer).observe(away) is None


def test_the_gripper_closes_on_the_box_only_when_it_straddles_it() -> None:
    T_mark = np.eye(4)
    T_mark[:3, 3] = [6.3, 1.66, 0.85]
    grasp_pose = T_mark @ T_MARK_GRASP
    opening, why = close_gripper(grasp_pose, T_mark)
    assert why == "" and opening == pytest.approx(BOX_SIZE[1])
    # Turned 5 degrees about the vertical: the box's support across the fingers grows.
    turned = grasp_pose.copy()
    a = np.radians(5.0)
    c, s = np.cos(a), np.sin(a)
    turned[:3, :3] = grasp_pose[:3, :3] @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    opening, why = close_gripper(turned, T_mark)
    expected = BOX_SIZE[0] * np.sin(a) + BOX_SIZE[1] * np.cos(a)
    assert why == "" and opening == pytest.approx(expected)
    # 2 cm off across the fingers: the open fingers (140 mm) no longer straddle 115 mm.
    across = grasp_pose.copy()
    across[:3, 3] += 0.02 * grasp_pose[:3, 1]
    assert "landed on the box" in close_gripper(across, T_mark)[1]
    # Fingertips 6 cm too high (above the box) or 4 cm to the side of its end.
    high = grasp_pose.copy()
    high[2, 3] += 0.06
    assert "too high or too low" in close_gripper(high, T_mark)[1]
    beside = grasp_pose.copy()
    beside[:3, 3] += 0.09 * grasp_pose[:3, 0]
    assert "beside the box" in close_gripper(beside, T_mark)[1]
    assert GRIPPER_OPEN > BOX_SIZE[1]


_PRE_GRASP = pre_grasp_pose()


def _turned(X: np.ndarray, degrees: float) -> np.ndarray:
    """Return X with its rotation turned by `degrees` about the camera's x axis."""
    a = np.radians(degrees)
    R = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]])
    out = X.copy()
    out[:3, :3] = X[:3, :3] @ R
    return out


def test_grasp_episode_reports_its_phases_as_it_enters_them() -> None:
    mm = default_manipulator()
    X = mm.T_ee_camera  # the hand-eye estimate given to the controller (exact here)
    # A fetch that succeeds goes through every phase, in order.
    seen: list[str] = []
    e = grasp_episode(
        np.random.default_rng(5), mm, X, intrinsics=_intrinsics(), on_phase=seen.append
    )
    assert e.success and seen == list(GRASP_PHASES) and e.phase == "lift and carry"
    # A hand-eye estimate 3 cm off (same episode): the robot goes through every phase, and the
    # scoring finds the grasp about 3 cm off, over the 5 mm tolerance: failed in the grasp.
    shifted = X.copy()
    shifted[:3, 3] += [0.03, 0.0, 0.0]
    seen = []
    e = grasp_episode(
        np.random.default_rng(5), mm, shifted, intrinsics=_intrinsics(), on_phase=seen.append
    )
    assert not e.success and e.position_error_mm > 20.0
    assert seen == list(GRASP_PHASES) and e.phase == "grasp"
    assert e.reason.startswith("final pose error")
    # A camera believed turned 60 degrees: the first look cannot be reached or never sees the
    # mark, so the fetch fails in the approach and enters no later phase.
    seen = []
    e = grasp_episode(
        np.random.default_rng(5),
        mm,
        _turned(X, 60.0),
        intrinsics=_intrinsics(),
        on_phase=seen.append,
    )
    assert not e.success and seen == ["approach"] and e.phase == "approach"


def test_grasp_episode_fetches_the_box_where_the_prior_says() -> None:
    # The prior is the mark's pose as a semantic map holds it: a box on the table's near edge,
    # yawed 1 rad, outside the area the random episodes place their box in (y 1.60-1.72 m).
    mm = default_manipulator()
    X = mm.T_ee_camera  # the hand-eye estimate given to the controller (exact here)
    c, s = np.cos(1.0), np.sin(1.0)
    prior = np.eye(4)
    prior[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    prior[:3, 3] = [6.05, 1.56, 0.85]
    assert fetch_problem(mm, prior) is None
    successes = 0
    for seed in range(2):
        events: list[tuple[str, object]] = []  # the reports, in order
        e = grasp_episode(
            np.random.default_rng(seed),
            mm,
            X,
            intrinsics=_intrinsics(),
            T_world_prior=prior,
            on_joints=_recorder(events, "joints"),
            on_gripper=_recorder(events, "gripper"),
            on_box=_recorder(events, "box"),
        )
        # Scored against the twin's box, which lies off the prior by its 5 cm / 0.15 rad
        # errors: the controller found it from the prior and grasped it within spec 05's
        # 5 mm and 2 deg.
        successes += e.success
        assert e.position_error_mm < 5.0 and e.rotation_error_deg < 2.0, e
        # Every arm motion was reported, each within the arm's limits, and no joint moved
        # faster than the joint position control allows (JOINT_RATE over a 0.1 s step).
        q = np.array([v for kind, v in events if kind == "joints"])
        assert len(q) > 20 and np.all(mm.arm.within_limits(q, tol=1e-9))
        assert np.abs(np.diff(q, axis=0)).max() <= JOINT_RATE * 0.1 + 1e-12
        _assert_box_reports(events, mm, prior, e)
    assert successes == 2


def _recorder(events: list, kind: str):
    """Return a reporter that appends (kind, value) to events."""
    return lambda value: events.append((kind, value))


def _assert_box_reports(events: list, mm, prior: np.ndarray, e) -> None:
    """The box an episode reported (T_arm_box, its mark frame in the arm's base frame): on
    the table until the gripper closes, then held in the gripper as it lifts."""
    closed = [i for i, (kind, _) in enumerate(events) if kind == "gripper"][1]
    table = [T for kind, T in events[:closed] if kind == "box"]
    held = [(i, T) for i, (kind, T) in enumerate(events) if kind == "box" and i > closed]
    assert events[0][0] == "gripper" and events[1][0] == "box"  # before the robot moves
    # On the table (the map's height kept, 0.85 m) and face up, seen from the arm's base
    # (mounted upright 0.80 m above the floor): the base drives, so the box moves in its frame.
    table_arr = np.array(table)
    assert len(table) > 10
    np.testing.assert_allclose(table_arr[:, 2, 3], prior[2, 3] - mm.T_base_arm[2, 3], atol=1e-12)
    np.testing.assert_allclose(
        table_arr[:, :3, 2], np.tile([0.0, 0.0, 1.0], (len(table), 1)), atol=1e-12
    )
    assert np.ptp(table_arr[:, :2, 3], axis=0).max() > 0.05
    # Every box the lift reports comes just before the joints of the same step, and rides in
    # the end effector: T_ee_box is one constant transform, the grasp pose relative to the
    # mark (T_MARK_GRASP) inverted, off by the episode's own error against the twin's box
    # (plus its rotation error's lever: the mark is 0.05 m above the fingertips), centred
    # between the fingers.
    assert len(held) >= 3
    ee_box = []
    for i, T in held[1:]:
        kind, q = events[i + 1]
        assert kind == "joints"
        ee_box.append(invert_pose(mm.arm.fk(q)) @ T)
    ee_box = np.array(ee_box)
    np.testing.assert_allclose(ee_box, np.broadcast_to(ee_box[0], ee_box.shape), atol=1e-12)
    dp, dr = pose_error(ee_box[0], invert_pose(T_MARK_GRASP))
    assert np.degrees(dr) == pytest.approx(e.rotation_error_deg, abs=1e-9)
    assert dp <= e.position_error_mm / 1e3 + 0.05 * dr + 1e-12
    assert ee_box[0][1, 3] == pytest.approx(0.0, abs=1e-12)
    # Closed on, the box moved only sideways (onto the fingers' midline), then the lift took
    # it 0.10 m straight up (within the numerical IK's 1e-6 tolerance).
    at_close, lifted = held[0][1], held[-1][1]
    dp, dr = pose_error(at_close, table[-1])
    lever = 0.05 * np.radians(e.rotation_error_deg)
    assert dr < 1e-12 and dp <= e.position_error_mm / 1e3 + lever
    np.testing.assert_allclose(lifted[:3, 3] - at_close[:3, 3], [0.0, 0.0, 0.10], atol=1e-6)


def test_fetch_problem_names_what_stops_a_fetch() -> None:
    mm = default_manipulator()
    upright = np.eye(4)
    upright[:3, 3] = [6.3, 1.66, 0.85]
    assert fetch_problem(mm, upright) is None
    # A mark on a vertical face (a cupboard door): the controller grasps boxes by their top.
    side = upright.copy()
    side[:3, :3] = [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]
    assert "faces 90 deg away from up" in fetch_problem(mm, side)
    # A box in the bedroom: no base pose in the kitchen corridor reaches it.
    far = upright.copy()
    far[:3, 3] = [6.5, 4.5, 0.85]
    assert "no base pose in the kitchen corridor" in fetch_problem(mm, far)
