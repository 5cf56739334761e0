"""The projector and spot-following scenarios of the twin, on short runs."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from core.errors import InvalidInput
from core.localization import NetworkCamera
from core.navigation import AdaptiveLaw, Limits, detect_laser_spot, occupancy_grid, segment_is_free
from core.projector import project_path
from core.sim import spot_following
from core.sim.floor_camera import FLOOR_CAMERA_EXPOSURE, calibrate_floor_camera, floor_camera_at
from core.sim.motion import WorldState
from core.sim.projector import nominal_projector, twin_projector
from core.sim.render import Renderer, camera_model
from core.sim.scenarios.path_following import path_following, plan_tour
from core.sim.scenarios.projector_calibration import projector_calibration
from core.sim.scene import default_scene


@pytest.fixture(scope="module")
def cameras() -> list[NetworkCamera]:
    # The scenarios' default is the marker network calibration (a rendered drive of a minute
    # or more); these tests exercise the pipeline with exact cameras instead, so their spot
    # errors are the pixel noise's alone.
    scene = default_scene()
    out = []
    for c in scene.cameras:
        m = camera_model(c)
        out.append(
            NetworkCamera.from_pose(m.K, m.dist, m.T_world_camera, (m.width, m.height), m.name)
        )
    return out


def test_projector_calibration_scenario_reports_its_keys(cameras) -> None:
    # The two living-room cameras see the whole room (rendering fewer views keeps it short).
    living = [c for c in cameras if c.name.startswith("cam_living")]
    r = projector_calibration(default_scene(), 0, cameras=living, cameras_from="exact")
    assert r.spots_from == "detected in rendered images"
    d = r.to_dict()
    json.dumps(d)
    assert {"spots", "position_error_m", "rotation_error_deg"} <= d.keys()
    assert d["spots"] >= 12
    # The spots are detected in rendered images (laser on - off) to ~0.05 px, under a
    # millimetre on the floor at 3-5 m through f = 330 px; the mount then follows within a
    # few of its own standard deviations (reported beside).
    assert d["spot_error_rms_m"] < 0.005
    assert d["position_error_m"] < 3 * d["position_std_m"] + 0.005
    assert d["rotation_error_deg"] < 3 * d["rotation_std_deg"] + 0.05


def test_projector_calibration_on_the_calibrated_network_meets_the_goal() -> None:
    # The whole chain on a seed nothing was tuned on: the network calibrated by the rendered
    # marker drive (mast raised), the spots detected in rendered images and located through
    # it, then the mount. Issue goal: 1 cm and 0.2 deg; measured 4.4 mm and 0.075 deg here,
    # 2.6-9.8 mm on seeds 0-12.
    r = projector_calibration(default_scene(), 11)
    assert r.spots >= 12
    assert r.position_error_m < 0.01, r
    assert r.rotation_error_deg < 0.2, r


def test_planned_tour_is_collision_free_on_the_inflated_plan() -> None:
    scene = default_scene()
    path = plan_tour(scene)
    assert 10.0 < np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1)) < 11.5
    # The simplified tour may leave the grid's cells by up to PLAN_SIMPLIFY, which the
    # planning margin covers: it is free on the grid inflated by the bare robot radius.
    grid = occupancy_grid(scene, scene.robot.base_radius + spot_following.PLAN_MARGIN - 0.03, 0.05)
    o = np.asarray(grid.origin)
    for a, b in itertools.pairwise(path):
        assert segment_is_free(grid.free, (a - o) / 0.05, (b - o) / 0.05)


def test_path_following_runs_every_law_on_the_same_path() -> None:
    tour = ((1.6, 1.2), (4.0, 1.2))  # one straight leg keeps the test short
    # The installer's nominal model draws the spot a few centimetres off the plan (the twin's
    # mount differs from it); the robot follows the spot wherever it is drawn.
    scene = default_scene()
    r = path_following(scene, 0, tour=tour, projector=nominal_projector(scene))
    d = r.to_dict()
    json.dumps(d)
    # Every floor-camera frame was rendered and the spot detected in it; the camera's floor
    # plane came from a rendered view of the floor chessboard (0.5 mm thick: its distance is
    # that much short) on the camera's calibrated intrinsics, whose principal point (~0.3 px
    # off at f = 500 px) tilts the plane by a few hundredths of a degree (0.052 deg on seed
    # 101): 0.15 deg is three times that.
    assert d["source"] == "rendered"
    assert d["floor_normal_error_deg"] < 0.15 and d["floor_distance_error_m"] < 1e-3
    # The floor camera's own intrinsics (Zhang on rendered chessboard views), not its true
    # lens: its focal length within 0.2 % (measured 0.06 %).
    assert d["floor_camera_intrinsics_from"].startswith("Zhang calibration")
    assert 0.0 < d["floor_camera_focal_error_pct"] < 0.2
    assert set(d["laws"]) == {"state_feedback", "adaptive", "proportional"}
    for law in d["laws"].values():
        assert {"rms_m", "max_m", "steady_m"} <= law.keys()
        assert law["finish_s"] is not None
    laws = d["laws"]
    # The two model-based laws are several times better than the proportional baseline.
    assert laws["adaptive"]["rms_m"] * 3 < laws["proportional"]["rms_m"]
    assert laws["state_feedback"]["rms_m"] * 3 < laws["proportional"]["rms_m"]
    assert len(d["series"]["adaptive"]["t"]) == len(d["series"]["adaptive"]["error_m"])


def test_path_following_meets_the_goals_on_the_home_tour() -> None:
    # The whole chain on a seed nothing was tuned on (the laws' gains were chosen on seeds
    # 20-39): the network calibrated by the rendered marker drive, the projector by spots the
    # ceiling cameras see, the ~10 m living-room tour drawn at 0.3 m/s and followed with the
    # floor camera's rendered frames at 15 Hz and 100 ms latency. Issue goals: RMS under 1 cm
    # for both model-based laws, the adaptive law's steady error on straight stretches under
    # 5 mm, and both at least 3 times better than the proportional baseline on the same data.
    r = path_following(default_scene(), 61)
    assert r.source == "rendered" and 9.5 < r.path_length_m < 10.5
    assert (r.camera_hz, r.latency_s, r.spot_speed_mps) == (15.0, 0.1, 0.3)
    sf, ad, pr = (r.laws[k] for k in ("state_feedback", "adaptive", "proportional"))
    for law in (sf, ad, pr):
        assert law.finish_s is not None and law.lost_events == 0, law
    assert sf.rms_m < 0.01, sf
    assert ad.rms_m < 0.01, ad
    assert ad.steady_m < 0.005, ad
    assert 3 * sf.rms_m < pr.rms_m and 3 * ad.rms_m < pr.rms_m, r.laws


def test_floor_camera_frames_show_the_spot_where_it_is() -> None:
    # The floor camera on a robot in the living room, the spot 0.8 m ahead: rendered with the
    # camera's exposure, detected within a tenth of a pixel of its true (distorted)
    # projection.
    scene = default_scene()
    renderer = Renderer(scene, supersample=1)
    empty = WorldState(0.0, None, tuple((1e4, 1e4) for _ in scene.people))
    pose = (1.6, 1.2, 0.3)
    ahead = np.array([1.6 + 0.8 * np.cos(0.3), 1.2 + 0.8 * np.sin(0.3), 0.0])
    frame = renderer.render(
        floor_camera_at(pose), empty, rng=1, spot=ahead, exposure=FLOOR_CAMERA_EXPOSURE
    )
    assert frame.spot_visible
    det = detect_laser_spot(frame.image)
    assert det is not None and np.linalg.norm(det.pixel - frame.spot_pixel) < 0.1
    # Behind the robot: not seen, and nothing red is found instead.
    behind = np.array([1.6 - 0.8 * np.cos(0.3), 1.2 - 0.8 * np.sin(0.3), 0.0])
    frame = renderer.render(
        floor_camera_at(pose), empty, rng=1, spot=behind, exposure=FLOOR_CAMERA_EXPOSURE
    )
    assert not frame.spot_visible and detect_laser_spot(frame.image) is None
    # An exposure is a fraction of the full one.
    with pytest.raises(InvalidInput, match="exposure"):
        renderer.render(floor_camera_at(pose), empty, spot=ahead, exposure=0.0)


def test_simulate_following_reports_every_step_live() -> None:
    # A short straight leg, followed by the adaptive law; on_step sees exactly what the run
    # records, as it goes.
    scene = default_scene()
    traj = project_path(
        nominal_projector(scene),
        np.array([[1.6, 1.2], [2.6, 1.2]]),
        0.3,
        spot_acceleration=spot_following.SPOT_ACCELERATION,
        corner_radius=spot_following.CORNER_RADIUS,
    )
    limits = Limits(scene.robot.limits.max_speed, scene.robot.limits.max_turn_rate)
    seen: list[tuple[float, np.ndarray, np.ndarray, float]] = []
    run = spot_following.simulate_following(
        AdaptiveLaw(spot_following.LOOKAHEAD, limits),
        traj,
        twin_projector(scene, 1),
        calibrate_floor_camera(np.random.default_rng([1, 7])),
        spot_following.start_pose(traj),
        scene,
        1,
        on_step=lambda t, pose, spot, error: seen.append((t, pose.copy(), spot.copy(), error)),
    )
    n = len(run.time)
    assert run.pose.shape == (n, 3) and run.spot.shape == (n, 2) and len(seen) == n
    assert np.array_equal([s[0] for s in seen], run.time)
    assert np.array_equal(np.array([s[1] for s in seen]), run.pose)
    assert np.array_equal(np.array([s[2] for s in seen]), run.spot)
    assert np.array_equal([s[3] for s in seen], run.error)
    assert np.allclose(np.diff(run.time), spot_following.CONTROL_DT)
    # The recorded error is the control point's distance to the recorded spot (recomputed
    # here from the pose, vectorised, to float precision).
    c, s = np.cos(run.pose[:, 2]), np.sin(run.pose[:, 2])
    P = run.pose[:, :2] + spot_following.LOOKAHEAD * np.column_stack([c, s])
    assert np.allclose(np.linalg.norm(P - run.spot, axis=1), run.error, atol=1e-12)
    # The spot ends where the twin's true projector draws the leg's end (its mount error puts
    # it a few cm off the plan: the spec's 3 cm / 1 deg per axis at 3-4 m, under 0.2 m), and
    # the robot's control point is within 2 cm of it once it settled.
    assert np.linalg.norm(run.spot[-1] - [2.6, 1.2]) < 0.2
    assert run.error[-1] < 0.02
