"""The app drives the live 3D scene: rooms and cameras reach a real viser scene after commit."""

from __future__ import annotations

import socket

import pytest
from fastapi.testclient import TestClient

from server.app import create_app

K = [[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_registry_changes_reach_the_scene(make_settings, admin):
    port = _free_port()
    settings = make_settings(viser_enabled=True, viser_port=port)
    with TestClient(create_app(settings)) as client:
        scene = client.app.state.scene_sync.scene
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
    settings = make_settings(viser_enabled=True, viser_port=_free_port())
    with TestClient(create_app(settings)) as client:
        scene = client.app.state.scene_sync.scene
        assert scene.flush(10.0)
        assert [c.name for c in scene.cameras().values()] == ["c"]
