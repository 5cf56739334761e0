"""Robots, people, tracks and camera images in the live scene, against a real viser server."""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest

from core.errors import InvalidInput
from server.scene import MAX_TRACK_POINTS, CameraEntry, SceneService
from server.scene import _cameras as scene_cameras
from server.scene._geometry import matrix_from_quaternion
from tests.support.ports import free_port

# Poses are computed in float64 (half-angle quaternion about +Z) and stored as float64 by the
# handles; the round trip keeps ~1e-16, so 1e-9 still catches a float32 step or a wrong axis.
POSE_TOL = 1e-9
K = [[600.0, 0.0, 320.0], [0.0, 600.0, 240.0], [0.0, 0.0, 1.0]]


@pytest.fixture
def scene():
    service = SceneService("127.0.0.1", free_port(), image_interval=0.2, image_width=160)
    service.start()
    yield service
    service.stop()


def yaw(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def robot(x: float, y: float, theta: float, **extra) -> dict:
    return {"id": "robot-1", "kind": "robot", "x": x, "y": y, "theta": theta, **extra}


def test_robot_is_drawn_at_its_pose_with_a_heading_to_its_front(scene):
    scene.upsert_agent(robot(2.5, 1.25, 2.2, radius=0.2, height=0.35))
    assert scene.flush()
    find = scene.server.scene.get_handle_by_name
    frame = find("/agents/robot-1")
    body = find("/agents/robot-1/body")
    heading = find("/agents/robot-1/heading")
    assert frame is not None and body is not None and heading is not None
    np.testing.assert_allclose(frame.position, [2.5, 1.25, 0.0], rtol=0, atol=POSE_TOL)
    np.testing.assert_allclose(matrix_from_quaternion(frame.wxyz), yaw(2.2), atol=POSE_TOL)
    assert body.radius == pytest.approx(0.2) and body.height == pytest.approx(0.35)
    # The cylinder stands on the floor (centred at half its height, viser cylinders are +Z).
    np.testing.assert_allclose(body.position, [0, 0, 0.175], atol=1e-12)
    # The heading bar lies on the top, in front of the centre along the agent's +X: in the
    # world, the direction (cos 2.2, sin 2.2) from the robot.
    front = np.array(frame.position) + yaw(2.2) @ np.array(heading.position)
    direction = (front[:2] - [2.5, 1.25]) / np.linalg.norm(front[:2] - [2.5, 1.25])
    np.testing.assert_allclose(direction, [math.cos(2.2), math.sin(2.2)], atol=1e-12)
    assert front[2] > 0.35

    view = scene.agents()["robot-1"]
    assert view.kind == "robot" and view.node == "/agents/robot-1"
    np.testing.assert_allclose(view.pose.position, [2.5, 1.25, 0.0], atol=POSE_TOL)


def test_moving_an_agent_moves_its_frame_without_rebuilding_meshes(scene):
    scene.upsert_agent(robot(0.0, 0.0, 0.0))
    assert scene.flush()
    body = scene.server.scene.get_handle_by_name("/agents/robot-1/body")
    rng = np.random.default_rng(3)
    for x, y, theta in rng.uniform([-3, -3, -math.pi], [3, 3, math.pi], size=(20, 3)):
        scene.upsert_agent(robot(x, y, theta))
    assert scene.flush()
    frame = scene.server.scene.get_handle_by_name("/agents/robot-1")
    np.testing.assert_allclose(frame.position, [x, y, 0.0], rtol=0, atol=POSE_TOL)
    np.testing.assert_allclose(matrix_from_quaternion(frame.wxyz), yaw(theta), atol=POSE_TOL)
    # Same handle: only the pose travelled, not a new cylinder per update.
    assert scene.server.scene.get_handle_by_name("/agents/robot-1/body") is body

    scene.upsert_agent(robot(x, y, theta, radius=0.3))  # a new size rebuilds the body
    assert scene.flush()
    assert scene.server.scene.get_handle_by_name("/agents/robot-1/body").radius == 0.3


def test_person_has_a_body_and_a_head_and_kind_changes_redraw(scene):
    person = {"id": "p7", "kind": "person", "x": 4.0, "y": -1.0, "theta": 0.0, "height": 1.8}
    scene.upsert_agent(person)
    assert scene.flush()
    find = scene.server.scene.get_handle_by_name
    head = find("/agents/p7/head")
    assert find("/agents/p7/body") is not None and head is not None
    assert find("/agents/p7/heading") is None
    # The top of the head is the person's height.
    assert head.position[2] + head.radius == pytest.approx(1.8, abs=1e-12)
    assert find("/agents/p7/label").text == "p7"
    assert scene.agents()["p7"].radius == pytest.approx(0.22)  # the default for a person

    scene.upsert_agent({**person, "kind": "robot", "height": 0.3})
    assert scene.flush()
    assert find("/agents/p7/head") is None and find("/agents/p7/heading") is not None


def test_remove_agent_removes_its_nodes_and_track(scene):
    scene.upsert_agent(robot(1, 1, 0))
    scene.set_track("robot-1", [[0, 0], [1, 1]])
    assert scene.flush()
    scene.remove_agent("robot-1")
    scene.remove_agent("nobody")  # unknown ids are ignored
    assert scene.flush()
    assert scene.server.scene.get_handle_by_name("/agents/robot-1") is None
    assert scene.server.scene.get_handle_by_name("/tracks/robot-1") is None
    assert scene.agents() == {} and scene.tracks() == {}


def test_track_is_a_polyline_just_above_the_floor_and_bounded(scene):
    t = np.linspace(0, 2 * math.pi, 50)
    points = np.column_stack([2 + np.cos(t), 1 + np.sin(t)])
    scene.set_track(7, points.tolist())  # integer ids are accepted as their text
    assert scene.flush()
    handle = scene.server.scene.get_handle_by_name("/tracks/7")
    segments = np.asarray(handle.points)
    assert segments.shape == (49, 2, 3)
    np.testing.assert_allclose(segments[:, 0, :2], points[:-1], atol=1e-6)  # float32 on wire
    np.testing.assert_allclose(segments[:, 1, :2], points[1:], atol=1e-6)
    assert np.all(segments[..., 2] > 0) and np.all(segments[..., 2] < 0.05)

    long = np.column_stack([np.arange(2000.0) * 0.01, np.zeros(2000)])
    scene.set_track("7", long)
    assert scene.flush()
    kept = scene.tracks()["7"]
    assert len(kept) == MAX_TRACK_POINTS
    np.testing.assert_array_equal(kept, long[-MAX_TRACK_POINTS:])  # the newest points
    assert np.asarray(scene.server.scene.get_handle_by_name("/tracks/7").points).shape[0] == (
        MAX_TRACK_POINTS - 1
    )

    scene.set_track("7", [])
    assert scene.flush()
    assert scene.server.scene.get_handle_by_name("/tracks/7") is None
    assert "7" not in scene.tracks()


def test_bad_agents_tracks_and_images_are_refused_and_change_nothing(scene):
    scene.upsert_agent(robot(1, 2, 0.5))
    assert scene.flush()
    before = scene.agents()
    bad_agents = [
        robot(float("nan"), 2, 0),
        robot(1, 2, "north"),
        robot(1, 2, 0, radius=-0.1),
        robot(1, 2, 0, height=0),
        {**robot(1, 2, 0), "kind": "cat"},
        {**robot(1, 2, 0), "id": ""},
        {**robot(1, 2, 0), "id": "a/b"},
        {"id": "robot-1", "kind": "robot", "y": 2},
        ["not", "a", "mapping"],
    ]
    for agent in bad_agents:
        with pytest.raises(InvalidInput):
            scene.upsert_agent(agent)
    for points in ([[0, 0, 0], [1, 1, 1]], [[0, 0], [float("inf"), 1]], "abc", [[0, 0], [1]]):
        with pytest.raises(InvalidInput):
            scene.set_track("robot-1", points)
    with pytest.raises(InvalidInput):
        scene.remove_agent(None)
    frame = np.zeros((48, 64, 3), np.uint8)
    for image in (frame.astype(np.float32), frame[:, :, :2], np.zeros((0, 4, 3), np.uint8), [1]):
        with pytest.raises(InvalidInput):
            scene.set_camera_image(1, image)
    with pytest.raises(InvalidInput):
        scene.set_camera_image("front", frame)
    assert scene.flush()
    assert scene.agents() == before and scene.tracks() == {}
    # A refused image does not use up the camera's interval: a good one is taken right after.
    assert scene.set_camera_image(1, frame)


def test_camera_image_is_shown_downscaled_in_rgb_on_the_frustum(scene):
    T = np.eye(4)
    T[:3, 3] = [1.0, 1.0, 2.5]
    scene.upsert_camera(CameraEntry(3, "c3", 640, 480, K, T.tolist()))
    bgr = np.zeros((480, 640, 3), np.uint8)
    bgr[:, :320] = (255, 0, 0)  # blue left half (BGR)
    bgr[:, 320:] = (0, 0, 255)  # red right half
    assert scene.set_camera_image(3, bgr)
    assert scene.flush()
    frustum = scene.server.scene.get_handle_by_name("/cameras/3/frustum")
    shown = frustum.image
    assert shown.shape == (120, 160, 3)  # image_width 160 keeps the 4:3 aspect
    np.testing.assert_array_equal(shown[60, 10], [0, 0, 255])  # blue, now as RGB
    np.testing.assert_array_equal(shown[60, 150], [255, 0, 0])
    np.testing.assert_array_equal(scene.camera_image(3), shown)

    # A redraw of the camera (a new calibration) keeps its image.
    T[:3, 3] = [2.0, 1.0, 2.5]
    scene.upsert_camera(CameraEntry(3, "c3", 640, 480, K, T.tolist()))
    assert scene.flush()
    frustum = scene.server.scene.get_handle_by_name("/cameras/3/frustum")
    np.testing.assert_array_equal(frustum.image, shown)

    # An image for a camera not drawn yet waits for it; a grey image is shown as RGB.
    assert scene.set_camera_image(4, np.full((30, 40), 77, np.uint8))
    scene.upsert_camera(CameraEntry(4, "c4", 40, 30))
    assert scene.flush()
    small = scene.server.scene.get_handle_by_name("/cameras/4/frustum").image
    assert small.shape == (30, 40, 3) and np.all(small == 77)  # narrower than 160: as is

    scene.remove_camera(3)
    assert scene.flush()
    assert scene.camera_image(3) is None


def test_camera_images_are_throttled_per_camera(scene, monkeypatch):
    # The service's clock, stopped and moved by hand: the interval is tested exactly, however
    # slow the machine (a real 0.2 s could pass between two calls on a loaded runner).
    now = [1000.0]
    monkeypatch.setattr(scene_cameras.time, "monotonic", lambda: now[0])
    frames = [np.full((48, 64, 3), v, np.uint8) for v in (10, 20, 30)]
    assert scene.set_camera_image(1, frames[0])
    now[0] += 0.19
    assert not scene.set_camera_image(1, frames[1])  # within 0.2 s of the last accepted one
    assert scene.set_camera_image(2, frames[1])  # another camera has its own interval
    assert scene.flush()
    assert np.all(scene.camera_image(1) == 10) and np.all(scene.camera_image(2) == 20)
    now[0] += 0.011  # 0.201 s after the first image: the next one is taken
    assert scene.set_camera_image(1, frames[2])
    assert scene.flush()
    assert np.all(scene.camera_image(1) == 30)

    # Many threads sending frames at once: one image per camera gets in per interval.
    accepted = []

    def sender() -> None:
        accepted.append(sum(scene.set_camera_image(5, frames[0]) for _ in range(50)))

    threads = [threading.Thread(target=sender) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sum(accepted) == 1


def test_agent_updates_do_not_block_and_state_survives_a_restart():
    service = SceneService("127.0.0.1", free_port())
    service.upsert_agent(robot(1.0, 2.0, 0.1))  # before start: kept
    service.set_track("robot-1", [[0, 0], [1, 2]])
    service.start()
    try:
        assert service.flush()
        assert set(service.agents()) == {"robot-1"} and set(service.tracks()) == {"robot-1"}
        t0 = time.perf_counter()
        for i in range(500):  # a 10 Hz stream for almost a minute, sent at once
            service.upsert_agent(robot(i * 0.01, 2.0, 0.1))
        # Each call only records state (microseconds); a generous bound that calls waiting on
        # drawing or on the network (milliseconds each) would still break.
        assert time.perf_counter() - t0 < 1.0
        assert service.flush(timeout=1.0)
        frame = service.server.scene.get_handle_by_name("/agents/robot-1")
        np.testing.assert_allclose(frame.position, [4.99, 2.0, 0.0], atol=POSE_TOL)
        service.stop()
        service.start()
        assert service.flush()
        frame = service.server.scene.get_handle_by_name("/agents/robot-1")
        np.testing.assert_allclose(frame.position, [4.99, 2.0, 0.0], atol=POSE_TOL)
        assert service.server.scene.get_handle_by_name("/tracks/robot-1") is not None
    finally:
        service.stop()


def test_track_covariance_is_a_2_sigma_ellipse_at_the_newest_point(scene):
    # A covariance with axes 3 cm and 1 cm (1 sigma), the major one at 30 degrees from +X.
    angle = math.radians(30.0)
    R = yaw(angle)[:2, :2]
    cov = R @ np.diag([0.03**2, 0.01**2]) @ R.T
    scene.upsert_agent({"id": "p1", "kind": "person", "x": 2.0, "y": 1.0})
    scene.set_track("p1", [[0.0, 0.0], [1.0, 0.5], [2.0, 1.0]], cov=cov.tolist())
    assert scene.flush()
    disc = scene.server.scene.get_handle_by_name("/uncertainty/p1")
    assert disc is not None and disc.radius == 1.0
    # Semi-axes 2 sigma: 6 cm and 2 cm, to rounding of the eigen-decomposition.
    np.testing.assert_allclose(disc.scale, [0.06, 0.02, 1.0], rtol=1e-12)
    np.testing.assert_allclose(disc.position[:2], [2.0, 1.0], atol=1e-12)
    major = matrix_from_quaternion(disc.wxyz) @ [1.0, 0.0, 0.0]
    # The major axis is a direction, not a heading: compare up to sign.
    assert abs(abs(major @ [math.cos(angle), math.sin(angle), 0.0]) - 1.0) < 1e-12

    scene.set_track("p1", [[0.0, 0.0], [1.0, 0.5]])  # no covariance: the ellipse goes
    assert scene.flush()
    assert scene.server.scene.get_handle_by_name("/uncertainty/p1") is None
    for bad in (
        [[1.0, 0.2], [0.3, 1.0]],
        [[-1.0, 0.0], [0.0, 1.0]],
        [[1.0, 0.0]],
        [[np.nan, 0], [0, 1]],
    ):
        with pytest.raises(InvalidInput, match="covariance"):
            scene.set_track("p1", [[0.0, 0.0], [1.0, 0.5]], cov=bad)
    scene.set_track("p1", [[0.0, 0.0], [1.0, 0.5]], cov=cov)
    scene.remove_agent("p1")  # takes its track and ellipse with it
    assert scene.flush()
    assert scene.server.scene.get_handle_by_name("/uncertainty/p1") is None
