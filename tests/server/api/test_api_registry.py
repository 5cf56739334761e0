"""The registry API on a real database: health, CRUD, pagination, validation, auth."""

from __future__ import annotations

import numpy as np
import pytest
from alembic.script import ScriptDirectory

from server.db.migrate import alembic_config

K = [[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]]


def test_health_reports_backend_and_schema(client, database_url):
    response = client.get("/api/v1/health")
    assert response.status_code == 200
    body = response.json()
    assert body["status"] == "ok"
    assert body["database"] == ("postgresql" if database_url.startswith("postgresql") else "sqlite")
    head = ScriptDirectory.from_config(alembic_config(database_url)).get_current_head()
    assert body["schema_revision"] == head  # the latest migration
    assert body["version"]


def test_camera_crud_roundtrip(client, admin):
    created = client.post(
        "/api/v1/cameras", json={"name": "ceiling-1", "width": 640, "height": 480}, headers=admin
    )
    assert created.status_code == 201, created.text
    camera = created.json()
    assert isinstance(camera["id"], int)
    assert camera["status"] == "uncalibrated" and camera["K"] is None

    url = f"/api/v1/cameras/{camera['id']}"
    assert client.get(url, headers=admin).json()["name"] == "ceiling-1"

    patched = client.patch(url, json={"K": K, "dist": [0.1, -0.2, 0, 0, 0]}, headers=admin)
    assert patched.status_code == 200, patched.text
    assert patched.json()["K"] == K and patched.json()["name"] == "ceiling-1"

    assert client.delete(url, headers=admin).status_code == 204
    assert client.get(url, headers=admin).status_code == 404


def test_camera_pose_from_position_and_quaternion(client, admin):
    # A half turn about z: R = diag(-1, -1, 1); quaternion (0, 0, 1, 0).
    body = {
        "name": "c",
        "width": 640,
        "height": 480,
        "position": [1.0, 2.0, 2.5],
        "quaternion_xyzw": [0.0, 0.0, 1.0, 0.0],
    }
    response = client.post("/api/v1/cameras", json=body, headers=admin)
    assert response.status_code == 201, response.text
    T = response.json()["T_world_camera"]
    expected = [[-1, 0, 0, 1.0], [0, -1, 0, 2.0], [0, 0, 1, 2.5], [0, 0, 0, 1]]
    assert np.allclose(T, expected, atol=1e-12)


@pytest.mark.parametrize(
    ("resource", "body"),
    [
        ("spaces", {"name": "flat"}),
        ("projectors", {"name": "beamer", "width": 1920, "height": 1080}),
        ("robots", {"name": "arm", "kinematic_model": {"dh": [[0, 0.1, 0, 1.57]]}}),
        ("landmarks", {"kind": "qr", "payload": "kitchen", "size_m": 0.12}),
    ],
)
def test_other_resources_crud(client, admin, resource, body):
    created = client.post(f"/api/v1/{resource}", json=body, headers=admin)
    assert created.status_code == 201, created.text
    item = created.json()
    url = f"/api/v1/{resource}/{item['id']}"
    key = next(iter(body))
    assert client.get(url, headers=admin).json()[key] == body[key]
    assert client.get(f"/api/v1/{resource}", headers=admin).json()["total"] == 1
    assert client.delete(url, headers=admin).status_code == 204
    assert client.get(url, headers=admin).status_code == 404


def test_rooms_belong_to_a_space(client, admin):
    polygon = [[0, 0], [5, 0], [5, 4], [0, 4]]
    orphan = client.post(
        "/api/v1/rooms", json={"space_id": 99, "name": "x", "polygon": polygon}, headers=admin
    )
    assert orphan.status_code == 422
    assert orphan.json()["errors"][0]["field"] == "space_id"

    space = client.post("/api/v1/spaces", json={"name": "flat"}, headers=admin).json()
    room = client.post(
        "/api/v1/rooms",
        json={"space_id": space["id"], "name": "living", "polygon": polygon},
        headers=admin,
    )
    assert room.status_code == 201, room.text
    listed = client.get(f"/api/v1/rooms?space_id={space['id']}", headers=admin).json()
    assert listed["total"] == 1 and listed["items"][0]["polygon"] == polygon
    # Deleting the space deletes its rooms (foreign keys are enforced on SQLite too).
    assert client.delete(f"/api/v1/spaces/{space['id']}", headers=admin).status_code == 204
    assert client.get("/api/v1/rooms", headers=admin).json()["total"] == 0


def test_devices_of_one_space_and_of_none(client, admin):
    bodies = {
        "cameras": {"width": 640, "height": 480},
        "landmarks": {"kind": "qr", "size_m": 0.1},
        "projectors": {"width": 1, "height": 1},
        "robots": {},
    }
    home, flat = (
        client.post("/api/v1/spaces", json={"name": name}, headers=admin).json()["id"]
        for name in ("home", "flat")
    )
    for resource, fields in bodies.items():
        ids = {}
        for label, space in (("home", home), ("flat", flat), ("none", None)):
            body = {**fields, "space_id": space}
            body["payload" if resource == "landmarks" else "name"] = label
            response = client.post(f"/api/v1/{resource}", json=body, headers=admin)
            assert response.status_code == 201, response.text
            ids[label] = response.json()["id"]

        def listed(query: str, resource: str = resource) -> set[int]:
            response = client.get(f"/api/v1/{resource}?{query}", headers=admin)
            assert response.status_code == 200, response.text
            return {row["id"] for row in response.json()["items"]}

        assert listed(f"space_id={home}") == {ids["home"]}, resource
        assert listed(f"space_id={home}&unassigned=true") == {ids["home"], ids["none"]}, resource
        assert listed("unassigned=true") == {ids["none"]}, resource
        assert listed("unassigned=false") == set(ids.values()), resource
        bad = client.get(f"/api/v1/{resource}?unassigned=maybe", headers=admin)
        assert bad.status_code == 422, resource


def test_pagination_windows_and_total(client, admin):
    for i in range(7):
        body = {"name": f"cam-{i}", "width": 640, "height": 480}
        assert client.post("/api/v1/cameras", json=body, headers=admin).status_code == 201
    page = client.get("/api/v1/cameras?limit=3&offset=5", headers=admin).json()
    assert page["total"] == 7 and page["limit"] == 3 and page["offset"] == 5
    assert [c["name"] for c in page["items"]] == ["cam-5", "cam-6"]
    bad = client.get("/api/v1/cameras?limit=0", headers=admin)
    assert bad.status_code == 422
    assert bad.json()["errors"][0] == {
        "field": "limit",
        "location": "query",
        "reason": bad.json()["errors"][0]["reason"],
    }


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ({"width": 640, "height": 480}, "name"),
        ({"name": "c", "width": -1, "height": 480}, "width"),
        ({"name": "c", "width": 640, "height": "tall"}, "height"),
        ({"name": "c", "width": 640, "height": 480, "K": [[1, 0], [0, 1]]}, "K"),
        ({"name": "c", "width": 640, "height": 480, "K": [[0, 0, 1], [0, 1, 1], [0, 0, 1]]}, "K"),
        ({"name": "c", "width": 640, "height": 480, "dist": [0.1, 0.2, 0.3]}, "dist"),
        (
            {"name": "c", "width": 640, "height": 480, "T_world_camera": [[2, 0, 0, 0]] * 4},
            "T_world_camera",
        ),
        ({"name": "c", "width": 640, "height": 480, "colour": "red"}, "colour"),
        ({"name": "c\u0000", "width": 640, "height": 480}, "name"),
    ],
)
def test_invalid_camera_names_the_field(client, admin, body, field):
    response = client.post("/api/v1/cameras", json=body, headers=admin)
    assert response.status_code == 422, response.text
    assert response.headers["content-type"].startswith("application/problem+json")
    problem = response.json()
    assert problem["status"] == 422 and problem["title"] and problem["detail"]
    fields = [e["field"].split(".")[0] for e in problem["errors"]]
    assert field in fields, problem
    assert all(e["reason"] for e in problem["errors"])


def test_non_finite_and_malformed_json_are_4xx(client, admin):
    nan = client.post(
        "/api/v1/landmarks",
        content=b'{"kind": "qr", "size_m": NaN}',
        headers={**admin, "Content-Type": "application/json"},
    )
    assert nan.status_code == 422
    broken = client.post(
        "/api/v1/spaces",
        content=b'{"name": ',
        headers={**admin, "Content-Type": "application/json"},
    )
    assert broken.status_code == 422
    huge_id = client.get(f"/api/v1/cameras/{2**40}", headers=admin)
    assert huge_id.status_code == 422


def test_patch_refuses_null_for_required_fields(client, admin):
    camera = client.post(
        "/api/v1/cameras", json={"name": "c", "width": 640, "height": 480}, headers=admin
    ).json()
    response = client.patch(f"/api/v1/cameras/{camera['id']}", json={"name": None}, headers=admin)
    assert response.status_code == 422
    assert response.json()["errors"][0]["field"] == "name"


def test_writes_and_reads_need_a_token(client, admin):
    body = {"name": "c", "width": 640, "height": 480}
    no_token = client.post("/api/v1/cameras", json=body)
    assert no_token.status_code == 401
    assert no_token.headers["www-authenticate"] == "Bearer"
    bad = client.post("/api/v1/cameras", json=body, headers={"Authorization": "Bearer nope"})
    assert bad.status_code == 401
    assert client.get("/api/v1/cameras").status_code == 401

    made = client.post("/api/v1/tokens", json={"name": "viewer", "scopes": ["read"]}, headers=admin)
    assert made.status_code == 201, made.text
    reader = {"Authorization": f"Bearer {made.json()['token']}"}
    assert client.get("/api/v1/cameras", headers=reader).status_code == 200
    assert client.post("/api/v1/cameras", json=body, headers=reader).status_code == 403
    assert client.get("/api/v1/tokens", headers=reader).status_code == 403

    # The token is shown once: listings carry names and scopes only.
    listed = client.get("/api/v1/tokens", headers=admin).json()
    assert listed["total"] == 1 and "token" not in listed["items"][0]

    writer_body = {"name": "ingest", "scopes": ["write"]}
    writer_token = client.post("/api/v1/tokens", json=writer_body, headers=admin).json()["token"]
    writer = {"Authorization": f"Bearer {writer_token}"}
    assert client.post("/api/v1/cameras", json=body, headers=writer).status_code == 201
    assert client.post("/api/v1/tokens", json=writer_body, headers=writer).status_code == 403

    assert client.delete(f"/api/v1/tokens/{made.json()['id']}", headers=admin).status_code == 204
    assert client.get("/api/v1/cameras", headers=reader).status_code == 401


def test_tokens_are_stored_hashed(client, admin, database_url):
    from sqlalchemy import create_engine, text

    token = client.post(
        "/api/v1/tokens", json={"name": "t", "scopes": ["read"]}, headers=admin
    ).json()["token"]
    engine = create_engine(database_url)
    with engine.connect() as connection:
        stored = connection.execute(text("SELECT token_hash FROM api_tokens")).scalars().all()
    engine.dispose()
    import hashlib

    assert stored == [hashlib.sha256(token.encode()).hexdigest()]


def test_public_reads_open_gets_only(make_settings):
    from fastapi.testclient import TestClient

    from server.app import create_app

    with TestClient(create_app(make_settings(public_reads=True))) as client:
        assert client.get("/api/v1/cameras").status_code == 200
        body = {"name": "c", "width": 640, "height": 480}
        assert client.post("/api/v1/cameras", json=body).status_code == 401


def test_request_size_limit(make_settings, admin):
    from fastapi.testclient import TestClient

    from server.app import create_app

    with TestClient(create_app(make_settings(max_request_bytes=4096))) as client:
        big = {"name": "s", "description": "x" * 8000}
        response = client.post("/api/v1/spaces", json=big, headers=admin)
        assert response.status_code == 413
        assert response.json()["status"] == 413


def test_scene_link_uses_the_callers_host(client):
    response = client.get("/api/v1/scene", headers={"Host": "livingroom.local:8000"})
    # The scene is served through the API's own origin (its proxy under /api/v1/scene/view/).
    # No scene runs in this process: it shows no space.
    assert response.json() == {
        "viser_url": "http://livingroom.local:8000/api/v1/scene/view/",
        "space_id": None,
    }


def test_openapi_documents_the_api(client):
    schema = client.get("/api/v1/openapi.json").json()
    assert "/api/v1/cameras" in schema["paths"]
    assert "/api/v1/calibration-runs/upload" in schema["paths"]
    assert "HTTPBearer" in schema["components"]["securitySchemes"]


def test_names_are_unique_where_users_tell_things_apart(client, admin):
    home = client.post("/api/v1/spaces", json={"name": "home"}, headers=admin).json()["id"]
    other = client.post("/api/v1/spaces", json={"name": "flat"}, headers=admin).json()["id"]
    assert client.post("/api/v1/spaces", json={"name": "home"}, headers=admin).status_code == 409
    body = {"name": "hall", "width": 640, "height": 480, "space_id": home}
    first = client.post("/api/v1/cameras", json=body, headers=admin)
    assert first.status_code == 201
    again = client.post("/api/v1/cameras", json=body, headers=admin)
    # A camera node finds its camera by name within its space: a second one is refused by name.
    assert again.status_code == 409, again.text
    assert again.json()["errors"][0]["field"] == "name"
    assert (
        f"camera {first.json()['id']}" in again.json()["detail"]
        and "'hall'" in again.json()["detail"]
    )
    # The same name in another space is another camera.
    elsewhere = client.post("/api/v1/cameras", json={**body, "space_id": other}, headers=admin)
    assert elsewhere.status_code == 201
    # Renaming or moving onto a taken name is refused too; nothing changes.
    moved = client.patch(
        f"/api/v1/cameras/{elsewhere.json()['id']}", json={"space_id": home}, headers=admin
    )
    assert moved.status_code == 409
    kept = client.get(f"/api/v1/cameras/{elsewhere.json()['id']}", headers=admin).json()
    assert kept["space_id"] == other
    # Renaming a camera to its own name is no clash.
    same = client.patch(
        f"/api/v1/cameras/{first.json()['id']}", json={"name": "hall"}, headers=admin
    )
    assert same.status_code == 200
    room = {"name": "kitchen", "space_id": home, "polygon": [[0, 0], [3, 0], [3, 2], [0, 2]]}
    assert client.post("/api/v1/rooms", json=room, headers=admin).status_code == 201
    assert client.post("/api/v1/rooms", json=room, headers=admin).status_code == 409
