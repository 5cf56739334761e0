"""The app drives the live 3D scene: rooms and cameras reach a real viser scene after commit."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from tests.support.ports import free_port

K = [[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]]


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_registry_changes_reach_the_scene(make_settings, admin):
    port = free_port()
    settings = make_settings(viser_enabled=True, viser_port=port)
    with TestClient(create_app(settings)) as client:
        scene = client.app.state.runtime.scene_sync.scene
        assert scene is not None and scene.running
        assert client.get("/api/v1/health").json()["scene"] is True
        assert client.get("/api/v1/scene").json()["viser_url"].endswith("/api/v1/scene/view/")

        space = client.post("/api/v1/spaces", json={"name": "flat"}, headers=admin).json()
        polygon = [[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [0.0, 3.0]]
        room = {"space_id": space["id"], "name": "living", "polygon": polygon}
        assert client.post("/api/v1/rooms", json=room, headers=admin).status_code == 201
        camera = client.post(
            "/api/v1/cameras",
            json={
                "name": "ceiling",
                "width": 640,
                "height": 480,
                "K": K,
                "position": [2.0, 1.5, 2.5],
                "quaternion_xyzw": [1.0, 0.0, 0.0, 0.0],
            },
            headers=admin,
        ).json()
        assert scene.flush(10.0)
        assert [r.name for r in scene.rooms()] == ["living"]
        drawn = scene.cameras()[camera["id"]]
        assert drawn.has_intrinsics and drawn.has_pose

        client.delete(f"/api/v1/cameras/{camera['id']}", headers=admin)
        assert scene.flush(10.0)
        assert camera["id"] not in scene.cameras()
    assert not scene.running  # the lifespan stopped it


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_scene_is_loaded_from_the_database_at_start(make_settings, admin):
    with TestClient(create_app(make_settings())) as client:
        client.post(
            "/api/v1/cameras", json={"name": "c", "width": 640, "height": 480}, headers=admin
        )
    settings = make_settings(viser_enabled=True, viser_port=free_port())
    with TestClient(create_app(settings)) as client:
        scene = client.app.state.runtime.scene_sync.scene
        assert scene.flush(10.0)
        assert [c.name for c in scene.cameras().values()] == ["c"]


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_the_scene_shows_one_space_at_a_time(make_settings, admin):
    settings = make_settings(viser_enabled=True, viser_port=free_port())
    with TestClient(create_app(settings)) as client:
        scene = client.app.state.runtime.scene_sync.scene
        polygons = {"home": [[0, 0], [5, 0], [5, 4], [0, 4]], "flat": [[0, 0], [3, 0], [3, 9.6]]}
        spaces, cameras = {}, {}
        for name, polygon in polygons.items():
            space = client.post("/api/v1/spaces", json={"name": name}, headers=admin).json()["id"]
            room = {"space_id": space, "name": f"{name}-room", "polygon": polygon}
            assert client.post("/api/v1/rooms", json=room, headers=admin).status_code == 201
            body = {"name": f"{name}-cam", "width": 640, "height": 480, "space_id": space}
            cameras[name] = client.post("/api/v1/cameras", json=body, headers=admin).json()["id"]
            spaces[name] = space
        body = {"name": "spare", "width": 640, "height": 480}
        spare = client.post("/api/v1/cameras", json=body, headers=admin).json()["id"]

        # The first space until another is chosen; a camera of no space is shown in any.
        assert client.get("/api/v1/scene").json()["space_id"] == spaces["home"]
        assert scene.flush(10.0)
        assert [r.name for r in scene.rooms()] == ["home-room"]
        assert set(scene.cameras()) == {cameras["home"], spare}

        answer = client.put("/api/v1/scene", json={"space_id": spaces["flat"]}, headers=admin)
        assert answer.status_code == 200 and answer.json()["space_id"] == spaces["flat"]
        assert scene.flush(10.0)
        assert [r.name for r in scene.rooms()] == ["flat-room"]
        assert set(scene.cameras()) == {cameras["flat"], spare}
        # A camera moved to the space not shown leaves the scene.
        move = {"space_id": spaces["home"]}
        client.patch(f"/api/v1/cameras/{cameras['flat']}", json=move, headers=admin)
        assert scene.flush(10.0)
        assert set(scene.cameras()) == {spare}

        missing = client.put("/api/v1/scene", json={"space_id": 999}, headers=admin)
        assert missing.status_code == 404
        assert client.put("/api/v1/scene", json={"space_id": spaces["home"]}).status_code == 401
        assert client.get("/api/v1/scene").json()["space_id"] == spaces["flat"]
