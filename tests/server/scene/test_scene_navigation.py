"""The projector (mount frame and beam) and the planned path in the live scene, against a real
viser server on a free loopback port."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInput
from core.sim import default_scene
from core.sim.projector import nominal_projector
from server.scene import ProjectorEntry
from server.scene._geometry import matrix_from_quaternion

# As in test_scene_service: poses go through float64 end to end (~1e-15); 1e-9 still catches
# a float32 step or a wrong axis convention.
POSE_TOL = 1e-9


def test_planned_path_and_projector_are_drawn_where_given(scene):
    path = [[1.0, 2.5], [3.0, 2.0], [3.5, 1.6]]
    T = nominal_projector(default_scene()).T_world_base
    scene.set_planned_path(path)
    scene.set_projector(ProjectorEntry("laser", T.tolist(), path[0]))
    assert scene.flush()
    find = scene.server.scene.get_handle_by_name
    # The path: one segment per leg, just above the floor, through the given points.
    segments = find("/navigation/path").points
    assert segments.shape == (2, 2, 3)
    np.testing.assert_allclose(segments[:, 0, :2], path[:-1], atol=1e-6)  # float32 in viser
    np.testing.assert_allclose(segments[:, 1, :2], path[1:], atol=1e-6)
    assert np.all((segments[..., 2] > 0) & (segments[..., 2] < 0.05))
    # The projector's frame is its mount pose (the quaternion round trip keeps ~1e-15).
    frame = find("/navigation/projector")
    np.testing.assert_allclose(frame.position, T[:3, 3], atol=POSE_TOL)
    np.testing.assert_allclose(matrix_from_quaternion(frame.wxyz), T[:3, :3], atol=POSE_TOL)
    assert find("/navigation/projector/label").text == "laser"
    # The beam runs from the mount to the spot on the floor.
    beam = find("/navigation/beam").points
    np.testing.assert_allclose(beam[0, 0], T[:3, 3], atol=1e-5)
    np.testing.assert_allclose(beam[0, 1], [*path[0], 0.0], atol=1e-6)
    view = scene.projector()
    assert view is not None and view.name == "laser" and view.spot == tuple(path[0])
    np.testing.assert_allclose(scene.planned_path(), path)

    # Cleared: the path by an empty list, the projector (and its beam) by None.
    scene.set_planned_path([])
    scene.set_projector(None)
    assert scene.flush()
    for node in ("/navigation/path", "/navigation/projector", "/navigation/beam"):
        assert find(node) is None, node
    assert scene.projector() is None and scene.planned_path().shape == (0, 2)


def test_bad_path_or_projector_is_refused_and_changes_nothing(scene):
    scene.set_planned_path([[0.0, 0.0], [1.0, 0.0]])
    assert scene.flush()
    for bad in ([[0.0, 0.0]], [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], [[0.0, np.nan], [1.0, 0.0]]):
        with pytest.raises(InvalidInput, match="planned path"):
            scene.set_planned_path(bad)
    skew = np.eye(4)
    skew[0, 1] = 0.3  # not a rotation
    with pytest.raises(InvalidInput, match="T_world_projector"):
        scene.set_projector(ProjectorEntry("p", skew.tolist()))
    with pytest.raises(InvalidInput, match="spot"):
        scene.set_projector(ProjectorEntry("p", np.eye(4).tolist(), [1]))
    assert scene.flush()
    np.testing.assert_allclose(scene.planned_path(), [[0.0, 0.0], [1.0, 0.0]])
    assert scene.projector() is None
