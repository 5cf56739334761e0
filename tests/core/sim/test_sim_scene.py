"""The scene schema: the shipped home loads, bad scenes are rejected with the field named."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from core.errors import InvalidInput
from core.geometry.rotations import matrix_to_quaternion, quaternion_to_matrix
from core.sim import default_scene, load_scene, scene_to_json
from core.sim._geometry import look_at_rotation
from core.sim.scene import Scene


@pytest.fixture(scope="module")
def home_dict() -> dict:
    return default_scene().model_dump(mode="json")


def test_default_home_matches_the_spec() -> None:
    s = default_scene()
    assert isinstance(s, Scene)
    assert len(s.rooms) == 3
    xy = np.array([p for r in s.rooms for p in r.polygon])
    extent = xy.max(0) - xy.min(0)
    assert extent == pytest.approx([8.0, 6.0], abs=0.5)  # "about 8 m x 6 m"
    # Two cameras in each of the rooms where people meet (living room, kitchen), one in the bedroom.
    assert len(s.cameras) == 5
    for c in s.cameras:
        assert c.pose.position[2] == pytest.approx(2.8)
        assert c.resolution == (640, 480)
        assert c.distortion.k1 < 0  # a real wide-angle lens: barrel distortion
        # Oblique: the optical axis is neither vertical nor horizontal.
        assert c.pose.look_at is not None
        d = np.subtract(c.pose.look_at, c.pose.position)
        tilt = np.degrees(np.arccos(-d[2] / np.linalg.norm(d)))
        assert 20 < tilt < 70
    assert s.projector is not None
    assert s.robot is not None and s.robot.marker is not None and s.robot.board is not None
    assert len(s.furniture) >= 4 and len(s.people) == 1
    assert any(w.doors for w in s.walls)


def test_text_dict_and_json_round_trip(home_dict: dict) -> None:
    s = default_scene()
    assert load_scene(home_dict) == s
    assert load_scene(scene_to_json(s)) == s
    assert load_scene(json.dumps(home_dict)) == s


@pytest.mark.parametrize(
    ("path", "value", "expected"),
    [
        (("cameras", 1, "intrinsics", "fx"), -300.0, "cameras.1.intrinsics.fx"),
        (("robot", "marker", "radius"), "big", "robot.marker.radius"),
        (("ceiling_height",), 0.0, "ceiling_height"),
        (("people", 0, "waypoints"), [[1.0, 1.0]], "people.0.waypoints"),
        (("floor", "colour_a"), [300, 0, 0], "floor.colour_a.0"),
        (("cameras", 0, "resolution"), [640], "cameras.0.resolution"),
    ],
)
def test_bad_values_name_the_field(
    home_dict: dict, path: tuple, value: object, expected: str
) -> None:
    d = copy.deepcopy(home_dict)
    node = d
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    with pytest.raises(InvalidInput, match=rf"{expected}\b"):
        load_scene(d)


def test_unknown_and_missing_fields_are_rejected(home_dict: dict) -> None:
    d = copy.deepcopy(home_dict)
    d["robot"]["marker"]["colour_name"] = "red"
    with pytest.raises(InvalidInput, match=r"robot\.marker\.colour_name: Extra inputs"):
        load_scene(d)
    d = copy.deepcopy(home_dict)
    del d["rooms"]
    with pytest.raises(InvalidInput, match=r"rooms: Field required"):
        load_scene(d)


def test_cross_field_rules(home_dict: dict) -> None:
    d = copy.deepcopy(home_dict)
    d["cameras"][0]["pose"]["quaternion_xyzw"] = [0.0, 0.0, 0.0, 1.0]
    with pytest.raises(InvalidInput, match=r"cameras\.0\.pose: .*exactly one of look_at"):
        load_scene(d)
    d = copy.deepcopy(home_dict)
    d["cameras"][2]["name"] = d["cameras"][0]["name"]
    with pytest.raises(InvalidInput, match="cameras names must be unique"):
        load_scene(d)
    d = copy.deepcopy(home_dict)
    d["walls"][4]["doors"][0]["offset"] = 5.5  # ends beyond the 6 m wall
    with pytest.raises(InvalidInput, match=r"walls\.4: .*beyond the wall"):
        load_scene(d)
    d = copy.deepcopy(home_dict)
    d["cameras"][0]["intrinsics"] = {"fx": 300.0, "fy": 300.0, "cx": 320.0}
    with pytest.raises(InvalidInput, match=r"cameras\.0\.intrinsics: .*fx, fy, cx, cy"):
        load_scene(d)


def test_full_K_is_accepted(home_dict: dict) -> None:
    d = copy.deepcopy(home_dict)
    d["cameras"][0]["intrinsics"] = {"K": [[300, 0, 320], [0, 301, 240], [0, 0, 1]]}
    s = load_scene(d)
    assert s.cameras[0].intrinsics.matrix()[1] == (0.0, 301.0, 240.0)


def test_text_that_is_not_a_scene() -> None:
    with pytest.raises(InvalidInput, match="neither valid YAML nor JSON"):
        load_scene("rooms: [unclosed")
    with pytest.raises(InvalidInput, match="mapping at the top level"):
        load_scene("- just\n- a list\n")
    with pytest.raises(InvalidInput, match=r"no camera named 'attic'.*cam_living_sw"):
        default_scene().camera("attic")


def test_pose_conventions() -> None:
    # look_at: z towards the target, x horizontal, y (image down) pointing downwards in world.
    R = look_at_rotation([0.0, 0.0, 2.8], [2.0, 1.0, 0.0])
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    d = np.array([2.0, 1.0, -2.8])
    np.testing.assert_allclose(R[:, 2], d / np.linalg.norm(d), atol=1e-12)
    assert abs(R[2, 0]) < 1e-12 and R[2, 1] < 0
    # Quaternions (x, y, z, w): 90 deg about Z maps x to y; matrix -> quaternion inverts it.
    q = np.array([0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)])
    np.testing.assert_allclose(quaternion_to_matrix(q) @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        q *= np.sign(q[3])
        np.testing.assert_allclose(matrix_to_quaternion(quaternion_to_matrix(q)), q, atol=1e-12)
