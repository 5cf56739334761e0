"""The live scene service against a real viser server on a free loopback port."""

from __future__ import annotations

import contextlib
import math
import threading
import time
import types
import urllib.request

import numpy as np
import pytest

from core.errors import InvalidInput
from server.scene import CameraEntry, RoomEntry, SceneService
from server.scene._geometry import matrix_from_quaternion
from tests.support.ports import free_port

# Poses go through float64 end to end (quaternion via Shepperd, handle stores float64), so the
# round trip T -> (wxyz, position) -> R keeps ~1e-15; 1e-9 leaves room and still catches any
# float32 step or a wrong axis convention.
POSE_TOL = 1e-9

K_ZHANG = [[832.5, 0.204494, 303.959], [0.0, 832.53, 206.585], [0.0, 0.0, 1.0]]
L_SHAPED_FLAT = [[0, 0], [6, 0], [6, 5], [3, 5], [3, 3], [0, 3]]


def random_pose(rng: np.random.Generator) -> np.ndarray:
    """Return a random camera-to-world transform (uniform rotation from a Gaussian quaternion)."""
    q = rng.normal(size=4)
    T = np.eye(4)
    T[:3, :3] = matrix_from_quaternion(q)
    T[:3, 3] = rng.uniform([-1, -1, 2], [6, 5, 3])
    return T


def camera(cam_id: int, T: np.ndarray | None, K=K_ZHANG, name: str | None = None) -> CameraEntry:
    return CameraEntry(
        cam_id, name or f"ceiling-{cam_id}", 640, 480, K, None if T is None else T.tolist()
    )


def test_serves_the_viser_page(scene):
    with urllib.request.urlopen(scene.url, timeout=5) as response:
        assert response.status == 200
        page = response.read().decode("utf-8", "replace")
    assert "<!doctype html>" in page.lower()
    assert scene.url == f"http://127.0.0.1:{scene.port}/"


def test_posed_camera_frustum_matches_the_given_transform(scene):
    rng = np.random.default_rng(7)
    T = random_pose(rng)
    scene.upsert_camera(camera(4, T))
    assert scene.flush()

    frame = scene.server.scene.get_handle_by_name("/cameras/4")
    frustum = scene.server.scene.get_handle_by_name("/cameras/4/frustum")
    label = scene.server.scene.get_handle_by_name("/cameras/4/label")
    assert frame is not None and frustum is not None and label is not None
    np.testing.assert_allclose(frame.position, T[:3, 3], rtol=0, atol=POSE_TOL)
    np.testing.assert_allclose(matrix_from_quaternion(frame.wxyz), T[:3, :3], rtol=0, atol=POSE_TOL)
    assert abs(np.linalg.norm(frame.wxyz) - 1.0) < POSE_TOL
    # Vertical field of view of a pinhole: 2 atan(h / 2 fy) (Zhang's camera: about 32 degrees).
    assert frustum.fov == pytest.approx(2 * math.atan(480 / (2 * 832.53)), abs=1e-12)
    assert frustum.aspect == pytest.approx(640 / 480, abs=1e-12)
    assert label.text == "ceiling-4"

    view = scene.cameras()[4]
    assert view.has_pose and view.has_intrinsics
    np.testing.assert_allclose(view.pose.position, T[:3, 3], rtol=0, atol=POSE_TOL)


def test_half_turn_poses_keep_full_precision(scene):
    # A ceiling camera looking straight down is a half turn about a horizontal axis: the
    # quaternion's w is 0, where naive trace-based conversions lose precision or divide by 0.
    for cam_id, axis in enumerate(np.eye(3), start=1):
        R = 2.0 * np.outer(axis, axis) - np.eye(3)  # rotation by pi about `axis`
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = [cam_id, 1.0, 2.7]
        scene.upsert_camera(camera(cam_id, T))
        assert scene.flush()
        frame = scene.server.scene.get_handle_by_name(f"/cameras/{cam_id}")
        np.testing.assert_allclose(matrix_from_quaternion(frame.wxyz), R, rtol=0, atol=POSE_TOL)


def test_camera_without_pose_is_parked_grey_and_labelled(scene):
    scene.set_floor_plan([RoomEntry(1, "Flat", L_SHAPED_FLAT)])
    scene.upsert_camera(camera(1, None, K=None, name="door"))
    scene.upsert_camera(camera(2, None, name="hall"))
    assert scene.flush()

    views = scene.cameras()
    assert not views[1].has_pose and not views[1].has_intrinsics
    assert views[1].label == "door (uncalibrated pose)"
    assert scene.server.scene.get_handle_by_name("/cameras/1/label").text == views[1].label
    # Parked in a row outside the plan's -Y side, one slot apart, both looking down.
    p1, p2 = np.array(views[1].pose.position), np.array(views[2].pose.position)
    assert p1[1] < 0 and p2[1] == p1[1]
    assert p2[0] - p1[0] == pytest.approx(0.9)
    R = matrix_from_quaternion(views[1].pose.wxyz)
    np.testing.assert_allclose(R[:, 2], [0, 0, -1], atol=1e-12)  # optical axis points down
    assert views[1].frustum.fov == pytest.approx(math.radians(60))

    # Once calibrated, the camera moves to its pose and the other parked one takes slot 0.
    T = random_pose(np.random.default_rng(3))
    scene.upsert_camera(camera(1, T, name="door"))
    assert scene.flush()
    views = scene.cameras()
    assert views[1].has_pose and views[1].label == "door"
    np.testing.assert_allclose(views[1].pose.position, T[:3, 3], atol=POSE_TOL)
    np.testing.assert_allclose(views[2].pose.position, p1, atol=1e-12)
    handle = scene.server.scene.get_handle_by_name("/cameras/2")
    np.testing.assert_allclose(handle.position, p1, atol=1e-12)


def test_remove_camera_removes_its_nodes(scene):
    scene.upsert_camera(camera(5, random_pose(np.random.default_rng(1))))
    assert scene.flush()
    assert scene.server.scene.get_handle_by_name("/cameras/5/frustum") is not None
    scene.remove_camera(5)
    scene.remove_camera(99)  # unknown ids are ignored
    assert scene.flush()
    assert scene.server.scene.get_handle_by_name("/cameras/5") is None
    assert scene.server.scene.get_handle_by_name("/cameras/5/frustum") is None
    assert 5 not in scene.cameras()


def test_floor_plan_draws_rooms_and_replaces_the_old_plan(scene):
    scene.set_floor_plan(
        [
            RoomEntry(1, "Living room", L_SHAPED_FLAT),
            RoomEntry(2, "Kitchen", [[6, 0], [9, 0], [9, 3], [6, 3]]),
        ]
    )
    assert scene.flush()
    find = scene.server.scene.get_handle_by_name
    for room_id in (1, 2):
        for part in ("walls", "fill", "label"):
            assert find(f"/floor/rooms/{room_id}/{part}") is not None
    assert find("/floor/rooms/1/label").text == "Living room"
    assert find("/floor/grid") is not None
    # The label sits at the L's area centroid: (6*3*(3, 1.5) + 3*2*(4.5, 4)) / 24.
    np.testing.assert_allclose(find("/floor/rooms/1/label").position[:2], [3.375, 2.125])

    scene.set_floor_plan([RoomEntry(3, "Study", [[0, 0], [3, 0], [3, 3]])])
    assert scene.flush()
    assert find("/floor/rooms/1/walls") is None
    assert find("/floor/rooms/3/walls") is not None
    assert [r.name for r in scene.rooms()] == ["Study"]


def test_bad_input_is_refused_and_changes_nothing(scene):
    scene.upsert_camera(camera(1, random_pose(np.random.default_rng(2))))
    assert scene.flush()
    before = scene.cameras()[1]
    sheared = np.eye(4)
    sheared[0, 1] = 0.3
    with pytest.raises(InvalidInput, match="rotation"):
        scene.upsert_camera(camera(1, sheared))
    with pytest.raises(InvalidInput, match="3x3"):
        scene.upsert_camera(camera(1, None, K=[[1, 2], [3, 4]]))
    with pytest.raises(InvalidInput, match="image size"):
        scene.upsert_camera(CameraEntry(1, "x", 0, 480))
    with pytest.raises(InvalidInput, match="polygon"):
        scene.set_floor_plan([RoomEntry(1, "line", [[0, 0], [1, 1]])])
    assert scene.flush()
    assert scene.cameras()[1] == before


def test_concurrent_updates_from_many_threads_end_consistent(scene):
    rng = np.random.default_rng(11)
    poses = {i: random_pose(rng) for i in range(1, 41)}

    def writer(ids: list[int]) -> None:
        for i in ids:
            scene.upsert_camera(camera(i, poses[i]))
            if i % 4 == 0:
                scene.remove_camera(i)

    threads = [threading.Thread(target=writer, args=(list(range(k, 41, 8)),)) for k in range(1, 9)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert scene.flush()
    expected = {i for i in poses if i % 4 != 0}
    assert set(scene.cameras()) == expected
    for i in expected:
        frame = scene.server.scene.get_handle_by_name(f"/cameras/{i}")
        np.testing.assert_allclose(frame.position, poses[i][:3, 3], atol=POSE_TOL)
    for i in set(poses) - expected:
        assert scene.server.scene.get_handle_by_name(f"/cameras/{i}") is None


def test_calls_do_not_block_and_changes_show_within_a_second(scene):
    rng = np.random.default_rng(5)
    t0 = time.perf_counter()
    for _ in range(200):
        scene.upsert_camera(camera(1, random_pose(rng)))
    call_time = time.perf_counter() - t0
    T = random_pose(rng)
    scene.upsert_camera(camera(1, T))
    assert scene.flush(timeout=1.0)
    # 200 calls only record state (microseconds each); a generous bound that a call that waited
    # on drawing or on the network would still break.
    assert call_time < 0.5
    frame = scene.server.scene.get_handle_by_name("/cameras/1")
    np.testing.assert_allclose(frame.position, T[:3, 3], atol=POSE_TOL)


def test_state_given_before_start_is_drawn_on_start():
    service = SceneService("127.0.0.1", free_port())
    T = random_pose(np.random.default_rng(9))
    service.set_floor_plan([RoomEntry(1, "Flat", L_SHAPED_FLAT)])
    service.upsert_camera(camera(2, T))
    assert service.cameras() == {} and not service.running
    service.start()
    try:
        service.start()  # a second start is a no-op
        assert service.flush()
        np.testing.assert_allclose(service.cameras()[2].pose.position, T[:3, 3], atol=POSE_TOL)
        assert service.server.scene.get_handle_by_name("/floor/rooms/1/fill") is not None
    finally:
        service.stop()
    assert not service.running
    service.stop()  # stopping twice is harmless


def test_camera_picker_lists_every_drawn_camera(scene):
    assert scene.server is not None
    scene.upsert_camera(camera(7, None, name="door"))
    scene.upsert_camera(camera(3, random_pose(np.random.default_rng(4)), name="hall"))
    assert scene.flush()
    assert scene.camera_options() == ("hall (#3)", "door (#7)")
    assert scene._camera_picker.options == ("hall (#3)", "door (#7)")
    view = scene._camera_for_option("door (#7)")
    assert view is not None and view.id == 7
    scene.remove_camera(3)
    scene.remove_camera(7)
    assert scene.flush()
    assert scene._camera_picker.options == ("(no cameras)",)


def test_view_through_camera_puts_the_viewer_at_its_pose(scene):
    T = random_pose(np.random.default_rng(8))
    scene.upsert_camera(camera(2, T, name="hall"))
    assert scene.flush()

    class FakeClient:  # what the button callback gets: a client with a camera and atomic()
        def __init__(self):
            self.camera = types.SimpleNamespace(position=None, wxyz=None, fov=None)

        def atomic(self):
            return contextlib.nullcontext()

    client = FakeClient()
    assert scene._look_through(client, "hall (#2)")
    np.testing.assert_allclose(client.camera.position, T[:3, 3], atol=POSE_TOL)
    np.testing.assert_allclose(matrix_from_quaternion(client.camera.wxyz), T[:3, :3], atol=POSE_TOL)
    assert client.camera.fov == pytest.approx(2 * math.atan(480 / (2 * 832.53)))
    assert not scene._look_through(client, "nobody (#9)")


def test_restart_draws_the_kept_state_again():
    service = SceneService("127.0.0.1", free_port())
    T = random_pose(np.random.default_rng(12))
    service.start()
    try:
        service.upsert_camera(camera(1, T))
        assert service.flush()
        service.stop()
        service.upsert_camera(camera(2, None))  # recorded while stopped
        assert not service.flush()  # nothing can be drawn until the next start
        service.start()
        assert service.flush()
        assert set(service.cameras()) == {1, 2}
        frame = service.server.scene.get_handle_by_name("/cameras/1")
        np.testing.assert_allclose(frame.position, T[:3, 3], atol=POSE_TOL)
    finally:
        service.stop()
