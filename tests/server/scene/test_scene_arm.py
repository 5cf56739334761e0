"""The arm on the robot in the live scene: its link frames are core.manipulation's forward
kinematics at the joint values given, inside the robot's agent frame; against a real viser
server on a free loopback port."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInput
from core.manipulation import default_arm
from core.sim.marked_box import BOX_SIZE, MARK_BOARD, MARK_POINTS, T_MARK_BOARD
from core.sim.render._textures import _board_texture
from server.scene import ArmEntry, Pose
from server.scene._arm import FRAME_NAMES
from server.scene._geometry import matrix_from_quaternion
from server.schemas.manipulation import TWIN_ARM

# Poses go through float64 end to end (matrix -> quaternion -> matrix keeps ~1e-15); 1e-9
# still catches a float32 step, a wrong frame order or a missing DH offset.
POSE_TOL = 1e-9
MOUNT = [[1.0, 0.0, 0.0, 0.05], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.80], [0, 0, 0, 1.0]]


def _arm(q=None, **extra) -> ArmEntry:
    fields = {"id": "7", "agent": "robot", "name": "puma", **TWIN_ARM, "T_robot_arm": MOUNT}
    return ArmEntry(**{**fields, "q": q, **extra})


def _pose(handle) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = matrix_from_quaternion(handle.wxyz)
    T[:3, 3] = handle.position
    return T


def _pose_of_view(pose: Pose) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = matrix_from_quaternion(pose.wxyz)
    T[:3, 3] = pose.position
    return T


def _assert_frames_are_fk(scene, q) -> None:
    find = scene.server.scene.get_handle_by_name
    node = "/agents/robot/arm-7"
    np.testing.assert_allclose(_pose(find(node)), MOUNT, atol=POSE_TOL)
    # The reference: the twin's arm (the same DH numbers TWIN_ARM carries) from core.
    expected = default_arm().frames(q)
    for i, name in enumerate(FRAME_NAMES):
        np.testing.assert_allclose(_pose(find(f"{node}/{name}")), expected[i], atol=POSE_TOL)
    np.testing.assert_allclose(_pose(find(f"{node}/ee")), default_arm().fk(q), atol=POSE_TOL)
    # The links join consecutive frame origins (float32 in viser).
    links = find(f"{node}/links").points
    np.testing.assert_allclose(links[:, 0], expected[:-1, :3, 3], atol=1e-6)
    np.testing.assert_allclose(links[:, 1], expected[1:, :3, 3], atol=1e-6)
    view = scene.arms()["7"]
    np.testing.assert_allclose(view.q, q, atol=0.0)


def test_arm_frames_are_forward_kinematics_on_the_robot_and_follow_joint_updates(scene):
    scene.upsert_agent({"id": "robot", "kind": "robot", "x": 2.0, "y": 1.0, "theta": 0.4})
    scene.set_arm(_arm())  # no q: the home pose
    assert scene.flush()
    home = np.asarray(TWIN_ARM["home"])
    _assert_frames_are_fk(scene, home)
    find = scene.server.scene.get_handle_by_name
    assert find("/agents/robot/arm-7/ee/finger_left") is not None  # the gripper

    # A joint update (as a fetch task reports them) moves the frames to FK at the new q.
    rng = np.random.default_rng(3)
    lim = default_arm().limits
    for _ in range(3):
        q = rng.uniform(lim[:, 0], lim[:, 1])
        scene.set_arm_joints("7", q)
        assert scene.flush()
        _assert_frames_are_fk(scene, q)

    # The robot drives on: the arm rides in its frame, untouched.
    scene.upsert_agent({"id": "robot", "kind": "robot", "x": 3.0, "y": 1.5, "theta": -1.0})
    assert scene.flush()
    _assert_frames_are_fk(scene, q)
    # The robot redrawn (a new size) drops its children; the arm is drawn again on it.
    scene.upsert_agent({"id": "robot", "kind": "robot", "x": 3.0, "y": 1.5, "radius": 0.25})
    assert scene.flush()
    _assert_frames_are_fk(scene, q)

    # The gripper opens and closes (as a fetch reports it): the fingers' inner faces are the
    # opening apart along the end effector's y, and the joints stay where they were.
    fingers = ("/agents/robot/arm-7/ee/finger_left", "/agents/robot/arm-7/ee/finger_right")
    for opening in (0.14, 0.115):
        scene.set_arm_gripper("7", opening)
        assert scene.flush()
        left, right = (np.asarray(find(name).position) for name in fingers)
        assert left[1] - right[1] - 0.01 == pytest.approx(opening, abs=1e-6)  # 10 mm fingers
        assert scene.arms()["7"].opening == opening
        _assert_frames_are_fk(scene, q)
    with pytest.raises(InvalidInput, match="opening"):
        scene.set_arm_gripper("7", -0.01)
    with pytest.raises(InvalidInput, match="opening"):
        scene.set_arm_gripper("7", float("nan"))
    with pytest.raises(InvalidInput, match="no arm"):
        scene.set_arm_gripper("8", 0.1)

    scene.remove_arm("7")
    assert scene.flush()
    assert find("/agents/robot/arm-7") is None and scene.arms() == {}


def test_arm_waits_for_its_robot_and_bad_arms_are_refused(scene):
    scene.set_arm(_arm())
    assert scene.flush()
    assert scene.arms() == {}  # no robot agent drawn yet
    scene.upsert_agent({"id": "robot", "kind": "robot", "x": 0.0, "y": 0.0})
    assert scene.flush()
    _assert_frames_are_fk(scene, np.asarray(TWIN_ARM["home"]))

    lim = default_arm().limits
    outside = lim[:, 1] + 0.1
    with pytest.raises(InvalidInput, match="outside its limits"):
        scene.set_arm_joints("7", outside)
    with pytest.raises(InvalidInput, match="no arm"):
        scene.set_arm_joints("8", TWIN_ARM["home"])
    skew = np.array(MOUNT)
    skew[0, 1] = 0.3
    with pytest.raises(InvalidInput, match="T_robot_arm"):
        scene.set_arm(_arm(T_robot_arm=skew.tolist()))
    with pytest.raises(InvalidInput, match=r"dh\.a"):
        scene.set_arm(_arm(dh={"a": [0.1] * 5, "d": [0] * 6, "alpha": [0] * 6}))
    assert scene.flush()
    _assert_frames_are_fk(scene, np.asarray(TWIN_ARM["home"]))  # nothing changed


def _yawed_box(yaw: float, position) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = position
    return T


def test_the_fetched_box_is_drawn_in_the_arm_frame_follows_its_reports_and_goes(scene):
    scene.upsert_agent({"id": "robot", "kind": "robot", "x": 2.0, "y": 1.0, "theta": 0.4})
    scene.set_arm(_arm())
    assert scene.flush()
    find = scene.server.scene.get_handle_by_name
    node = "/agents/robot/arm-7/box"
    assert find(node) is None and scene.arms()["7"].box is None

    # On the table ahead of the arm: drawn inside the arm's node (itself at the mount), so in
    # the robot's frame the box is at T_robot_arm @ T_arm_box.
    on_table = _yawed_box(0.7, [0.62, 0.08, 0.05])
    scene.set_arm_box("7", on_table)
    assert scene.flush()
    np.testing.assert_allclose(_pose(find(node)), on_table, atol=POSE_TOL)
    np.testing.assert_allclose(
        _pose(find("/agents/robot/arm-7")) @ _pose(find(node)), MOUNT @ on_table, atol=POSE_TOL
    )
    np.testing.assert_allclose(_pose_of_view(scene.arms()["7"].box), on_table, atol=POSE_TOL)
    # The twin's box (core.sim): 160 x 115 x 100 mm below its top, the mark frame's origin;
    # the print's paper 7 x 6 squares of 16 mm with an 8 mm border, 128 x 112 mm, on the top.
    body = find(f"{node}/body")
    np.testing.assert_allclose(body.dimensions, BOX_SIZE, atol=1e-7)  # float32 in viser
    np.testing.assert_allclose(body.position, [0.0, 0.0, -0.05], atol=1e-7)
    np.testing.assert_allclose(find(f"{node}/print").dimensions[:2], [0.128, 0.112], atol=1e-7)
    # Its dark squares are the renderer's print: every inner corner the detector finds
    # (MARK_POINTS, mark frame) is a corner of the drawn squares, and each drawn square's
    # centre is dark in the texture the twin's camera images are rendered from.
    squares = find(f"{node}/squares")
    vertices = np.asarray(squares.vertices, dtype=np.float64)
    for corner in MARK_POINTS:
        assert np.min(np.linalg.norm(vertices - corner, axis=1)) < 1e-7
    texture = _board_texture(MARK_BOARD, per_square=32)
    centres = vertices.reshape(-1, 4, 3).mean(axis=1)
    board = centres @ T_MARK_BOARD[:3, :3] - T_MARK_BOARD[:3, 3] @ T_MARK_BOARD[:3, :3]
    texel = MARK_BOARD.square_size / 32
    margin = round(MARK_BOARD.margin * 32)  # texels, then the squares from (-1, -1)
    col = np.floor(board[:, 0] / texel + margin + 32).astype(int)
    row = np.floor(board[:, 1] / texel + margin + 32).astype(int)
    assert len(centres) == 21 and np.all(texture[row, col, 0] < 128)  # 42 squares, half dark

    # The gripper holds it: re-posed as the task reports, and kept as the joints move.
    lifted = _yawed_box(-0.2, [0.5, -0.1, 0.25])
    scene.set_arm_box("7", lifted)
    q = np.asarray(TWIN_ARM["home"]) + 0.1
    scene.set_arm_joints("7", q)
    assert scene.flush()
    np.testing.assert_allclose(_pose(find(node)), lifted, atol=POSE_TOL)
    assert find(f"{node}/body") is not None
    _assert_frames_are_fk(scene, q)
    # The robot redrawn drops its children: the box is drawn again with the arm.
    scene.upsert_agent({"id": "robot", "kind": "robot", "x": 2.0, "y": 1.0, "radius": 0.25})
    assert scene.flush()
    np.testing.assert_allclose(_pose(find(node)), lifted, atol=POSE_TOL)

    # Bad poses and unknown arms are refused by name; nothing changes.
    skew = lifted.copy()
    skew[0, 1] = 0.3
    for bad, words in (
        (lifted[:3, :3], "finite 4x4"),
        (np.full((4, 4), np.nan), "finite 4x4"),
        (skew, "rotation"),
        ("box", "numeric"),
    ):
        with pytest.raises(InvalidInput, match=words):
            scene.set_arm_box("7", bad)
    with pytest.raises(InvalidInput, match="no arm '8'"):
        scene.set_arm_box("8", on_table)
    assert scene.flush()
    np.testing.assert_allclose(_pose(find(node)), lifted, atol=POSE_TOL)
    assert set(scene.arms()) == {"7"}

    # The task ended: the box goes, the arm stays.
    scene.remove_arm_box("7")
    assert scene.flush()
    assert find(node) is None and scene.arms()["7"].box is None
    _assert_frames_are_fk(scene, q)
    scene.remove_arm_box("7")  # nothing to remove
    scene.remove_arm_box("8")
    # Drawing the arm afresh (as a task starts or ends) draws it without a box.
    scene.set_arm_box("7", on_table)
    scene.set_arm(_arm())
    assert scene.flush()
    assert find(node) is None and scene.arms()["7"].box is None
