"""The default home's landmarks: payloads, placement where the head camera reads them, the
navigation graph they make, and what the ceiling cameras see of them."""

from __future__ import annotations

from itertools import combinations

import cv2
import numpy as np

from core.geometry.poses import planar_pose
from core.geometry.rotations import quaternion_to_matrix
from core.landmarks import NavigationMap, ObjectMark, Signpost, decode_payload
from core.localization.detect import detect_marker
from core.sim.head_camera import (
    head_camera,
    reading_standoff,
    robot_head_pose,
)
from core.sim.motion import WorldState
from core.sim.occluders import scene_occluders
from core.sim.render import Renderer
from core.sim.render.landmarks import render_scene_landmarks, scene_landmarks
from core.sim.scene import default_scene


def _room_of(scene, xy):  # type: ignore[no-untyped-def]
    for r in scene.rooms:
        poly = np.asarray(r.polygon, np.float32)
        if cv2.pointPolygonTest(poly, (float(xy[0]), float(xy[1])), False) > 0:
            return r.name
    return None


def test_default_home_landmarks_decode_and_sit_in_their_rooms() -> None:
    scene = default_scene()
    kinds = [lm.kind for lm in scene.landmarks]
    assert kinds.count("object_mark") == 10 and kinds.count("signpost") == 6
    records = [decode_payload(lm.payload) for lm in scene.landmarks]
    assert len({r.id for r in records}) == len(records)
    for lm, rec in zip(scene.landmarks, records, strict=True):
        assert isinstance(rec, ObjectMark if lm.kind == "object_mark" else Signpost)
        assert lm.size == (0.1 if lm.kind == "object_mark" else 0.2)
        R = quaternion_to_matrix(lm.pose.quaternion_xyzw)
        # 5 cm in front of the printed face is free floor of the room the payload names.
        front = np.asarray(lm.pose.position) + 0.05 * R[:, 2]
        assert _room_of(scene, front) == rec.room, lm.name
        if isinstance(rec, Signpost):
            # The signpost's payload carries its world pose: 0.1 mm and 1e-5 quantisation.
            np.testing.assert_allclose(rec.pose[:3], lm.pose.position, atol=1e-4)
            Rp = quaternion_to_matrix(rec.pose[3:])
            np.testing.assert_allclose(Rp, R, atol=1e-4)


def test_default_home_signposts_link_every_pair_of_rooms() -> None:
    scene = default_scene()
    nav = NavigationMap()
    for lm in scene.landmarks:
        rec = decode_payload(lm.payload)
        if isinstance(rec, Signpost):
            nav.observe(rec)
    assert nav.rooms == sorted(r.name for r in scene.rooms)
    for a, b in combinations(nav.rooms, 2):
        route = nav.route(a, b)
        assert route.rooms[0] == a and route.rooms[-1] == b


def test_every_landmark_reads_with_3px_modules_from_a_free_reading_pose() -> None:
    """Spec 07: each mark has a reachable reading pose where its modules span >= 3 px."""
    scene = default_scene()
    assert scene.robot is not None and scene.robot.head_camera is not None
    head = scene.robot.head_camera
    cam, _ = head_camera(scene)
    occ = scene_occluders(scene)
    marks = scene_landmarks(scene)
    for lm in marks:
        m = lm.T_world_mark[:3, 3]
        n = lm.T_world_mark[:3, 2].copy()
        n[2] = 0.0
        n /= np.linalg.norm(n)
        # The reading pose HeadRobot drives to, from the true pose (scoring the placement).
        d_h = reading_standoff(lm.kind, cam.K[0, 0], head.position[2] - m[2])
        base = m[:2] + n[:2] * (d_h + head.position[0])
        yaw = float(np.arctan2(-n[1], -n[0]))
        axis = np.array([*base, 0.0]) + planar_pose((0.0, 0.0, yaw))[:3, :3] @ head.position
        rel = m - axis
        pan = float(np.arctan2(rel[1], rel[0])) - yaw
        tilt = float(np.arctan2(-rel[2], np.hypot(rel[0], rel[1])))
        T = planar_pose((base[0], base[1], yaw)) @ robot_head_pose(head, pan, tilt)
        view, idx = render_scene_landmarks(cam, T, [lm], occ)
        assert idx == [0], f"{lm.name} is not in view from its reading pose"
        module = view.truth[0].module_px
        assert module is not None and module >= 3.0, (lm.name, module)
        # The base there clears every wall and piece of furniture.
        d = base - occ.centre
        c, s = np.cos(occ.yaw), np.sin(occ.yaw)
        local = np.abs(np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], 1))
        gap = np.linalg.norm(np.maximum(local - occ.half_size, 0.0), axis=1)
        low = occ.z[:, 0] < scene.robot.base_height
        assert np.min(gap[low]) > scene.robot.base_radius, lm.name


def test_ceiling_camera_sees_no_red_marker_without_the_robot() -> None:
    """The ceiling cameras draw the home's landmarks; with the robot away no red disc is found,
    though cam_kitchen_sw faces signpost_25, whose red rings (~208 px) are larger there than
    the robot's marker."""
    scene = default_scene()
    state = WorldState(0.0, None, tuple((0.8, 2.4) for _ in scene.people))
    frame = Renderer(scene).render("cam_kitchen_sw", state, rng=1)
    assert detect_marker(frame.image) is None
