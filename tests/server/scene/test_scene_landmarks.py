"""Landmarks, the semantic map and the navigation graph in the live scene, against a real viser
server on a free loopback port: drawn from a space's registry and maps through SceneSync, and
refused when malformed."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInput
from core.landmarks import decode_payload
from core.sim import default_scene
from core.sim._geometry import pose_matrix
from server.scene import LandmarkEntry, PlaceEntry, SemanticObjectEntry
from server.scene._geometry import matrix_from_quaternion
from server.services.scene_sync import SceneSync

# Poses go through float64 end to end (matrix -> quaternion -> matrix ~1e-15); 1e-9 still
# catches a float32 step or a wrong axis convention. Points (line segments, point clouds) are
# float32 in viser: ~1e-7 relative at a few metres.
POSE_TOL = 1e-9
POINT_TOL = 1e-5


def _T(pose: object) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = pose_matrix(pose)  # type: ignore[arg-type]
    return T


def _matrix(handle: object) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = matrix_from_quaternion(handle.wxyz)  # type: ignore[attr-defined]
    T[:3, 3] = handle.position  # type: ignore[attr-defined]
    return T


def test_a_space_with_landmarks_and_maps_is_drawn(client, admin, scene) -> None:
    """The default home's 16 landmarks registered with their poses, every one read once into
    the maps (through the API); SceneSync.load draws each landmark's frame at its pose with
    its name, each object at its mark's fused pose, each place and edge of the navigation
    map."""
    home = default_scene()
    space = client.post("/api/v1/spaces", json={"name": "home"}, headers=admin).json()["id"]
    T_world_cam = np.eye(4)
    T_world_cam[:3, 3] = [4.0, 3.0, 2.8]  # any known camera pose: the reads are given poses
    ids, observations = {}, []
    for lm in home.landmarks:
        T = _T(lm.pose)
        body = {
            "kind": "qr",
            "payload": lm.payload,
            "size_m": lm.size,
            "space_id": space,
            "T_world_landmark": T.tolist(),
        }
        created = client.post("/api/v1/landmarks", json=body, headers=admin)
        assert created.status_code == 201, created.text
        ids[lm.name] = created.json()["id"]
        observations.append(
            {
                "payload": lm.payload,
                "T_cam_mark": (np.linalg.inv(T_world_cam) @ T).tolist(),
                "cov": np.diag([1e-4] * 3 + [1e-4] * 3).tolist(),
                "T_world_camera": T_world_cam.tolist(),
            }
        )
    update = client.post(
        "/api/v1/maps/observations",
        json={"space_id": space, "observations": observations},
        headers=admin,
    )
    assert update.status_code == 200, update.text
    n_edges = update.json()["navigation_edges"]
    nav = client.get("/api/v1/maps/navigation", headers=admin).json()
    with client.app.state.runtime.session_factory() as session:
        SceneSync(scene).load(session)
    assert scene.flush()
    find = scene.server.scene.get_handle_by_name

    # Landmarks: one labelled frame each at its registered pose, a plate of its kind's colour.
    drawn = scene.landmarks()
    assert len(drawn) == len(home.landmarks) == 16
    for lm in home.landmarks:
        record = decode_payload(lm.payload)
        view = drawn[str(ids[lm.name])]
        assert (view.name, view.kind) == (f"#{record.id} {record.name}", record.kind)
        frame = find(view.node)
        np.testing.assert_allclose(_matrix(frame), _T(lm.pose), atol=POSE_TOL)
        assert find(f"{view.node}/label").text == view.name
        colour = (0, 0, 255) if record.kind == "object" else (255, 0, 0)
        assert tuple(find(f"{view.node}/plate").color) == colour

    # Semantic objects: at the pose of their one read (T_world_cam @ T_cam_mark: ~1e-15).
    objects = scene.semantic_objects()
    marks = [lm for lm in home.landmarks if lm.kind == "object_mark"]
    assert len(objects) == len(marks) == 10
    for lm in marks:
        record = decode_payload(lm.payload)
        view = objects[f"{space}:{record.id}"]
        assert (view.name, view.object_class) == (record.name, record.object_class)
        np.testing.assert_allclose(_matrix(find(view.node)), _T(lm.pose), atol=POSE_TOL)
        assert find(f"{view.node}/label").text == f"{record.name} ({record.object_class})"

    # The navigation graph: the API's places and edges, drawn just above the floor.
    places = {
        f"{space}:{f['properties']['id']}": f["geometry"]["coordinates"]
        for f in nav["features"]
        if f["properties"]["kind"] == "place"
    }
    graph = scene.navigation_graph()
    assert len(places) == 6 and set(graph.places) == set(places)
    cloud = find("/maps/navigation/places").points
    np.testing.assert_allclose(cloud[:, :2], [places[k] for k in graph.places], atol=POINT_TOL)
    assert np.all((cloud[:, 2] > 0) & (cloud[:, 2] < 0.05))
    for key, place in graph.places.items():
        assert find(f"/maps/navigation/labels/{key}").text == place.name
    # As stored by the map service (neighbour fields, places sharing a room): 6 for the home.
    assert n_edges == 6 and len(graph.edges) == n_edges
    segments = find("/maps/navigation/edges").points
    assert segments.shape == (n_edges, 2, 3)
    want = np.array([[places[a], places[b]] for a, b in graph.edges])
    np.testing.assert_allclose(segments[..., :2], want, atol=POINT_TOL)

    # Cleared: empty lists remove every node.
    scene.set_landmarks([])
    scene.set_semantic_objects([])
    scene.set_navigation_graph([], [])
    assert scene.flush()
    for node in ("/landmarks", "/maps/semantic", "/maps/navigation"):
        assert find(node) is None, node
    assert not scene.landmarks() and not scene.semantic_objects()


def test_malformed_landmarks_and_maps_are_refused_and_change_nothing(scene) -> None:
    T = np.eye(4)
    T[:3, 3] = [1.0, 2.0, 1.3]
    scene.set_landmarks([LandmarkEntry(1, "door", "signpost", 0.1, T)])
    assert scene.flush()
    skew = T.copy()
    skew[0, 1] = 0.3  # not a rotation
    bad_landmarks = [
        [LandmarkEntry(2, "", "", 0.1, skew)],
        [LandmarkEntry("a/b", "", "", 0.1, T)],
        [LandmarkEntry(2, "", "", -0.1, T)],
        [LandmarkEntry(2, "", "", 0.1, T), LandmarkEntry(2, "", "", 0.1, T)],
    ]
    for bad in bad_landmarks:
        with pytest.raises(InvalidInput):
            scene.set_landmarks(bad)
    with pytest.raises(InvalidInput, match="semantic object 1 pose"):
        scene.set_semantic_objects([SemanticObjectEntry("1", "", "", "", skew)])
    place = PlaceEntry("p", "door", "", [1.0, 2.0])
    with pytest.raises(InvalidInput, match="not listed"):
        scene.set_navigation_graph([place], [["p", "q"]])
    with pytest.raises(InvalidInput, match="itself"):
        scene.set_navigation_graph([place], [["p", "p"]])
    with pytest.raises(InvalidInput, match="position"):
        scene.set_navigation_graph([PlaceEntry("p", "", "", [1.0, np.nan])], [])
    assert scene.flush()
    assert list(scene.landmarks()) == ["1"]
    np.testing.assert_allclose(
        _matrix(scene.server.scene.get_handle_by_name("/landmarks/1")), T, atol=POSE_TOL
    )
