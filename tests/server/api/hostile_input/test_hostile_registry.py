"""Hostile values for the registry (robots, cameras, rooms): none can break a space for good;
each is refused where it is written, naming the field."""

from __future__ import annotations

import json
from typing import Any

import pytest

from tests.support.hostile_requests import RSS_BOUND_MB


def test_deep_free_form_json_is_refused_and_robots_stay_readable(case, home):
    deep: dict[str, Any] = {}
    node = deep
    for _ in range(500):
        node["a"] = {}
        node = node["a"]
    status, _, problem, growth, _ = case.send(
        "POST", "/api/v1/robots", {"name": "deep", "kinematic_model": deep}
    )
    assert status == 422
    assert "nest at most 32 levels" in json.dumps(problem)
    assert growth < RSS_BOUND_MB
    case.next_request_answered()
    status, _, _, _, _ = case.send("GET", "/api/v1/robots")
    assert status == 200


def _camera(space_id: int, **changes: Any) -> dict[str, Any]:
    body = {
        "name": "probe",
        "space_id": space_id,
        "width": 1280,
        "height": 720,
        "K": [[700, 0, 640], [0, 700, 360], [0, 0, 1]],
        "T_world_camera": [[1, 0, 0, 4], [0, -1, 0, 3], [0, 0, -1, 2.6], [0, 0, 0, 1]],
    }
    body.update(changes)
    return body


@pytest.mark.parametrize(
    ("changes", "field", "reason"),
    [
        ({"K": [[1e-300, 0, 640], [0, 700, 360], [0, 0, 1]]}, "K.0.0", "implausible"),
        ({"K": [[700, 0, 640], [0, 7e6, 360], [0, 0, 1]]}, "K.1.1", "implausible"),
        ({"K": [[700, 0, 9000], [0, 700, 360], [0, 0, 1]]}, "K.0.2", "outside"),
        ({"K": [[700, 300, 640], [0, 700, 360], [0, 0, 1]]}, "K.0.1", "skew"),
        ({"dist": [0.1, 0.0, 0.0, 0.0, 1e6]}, "dist", "below"),
    ],
)
def test_an_implausible_camera_model_is_refused_where_it_is_written(
    case, home, changes, field, reason
):
    space = home["space"]["id"]
    status, _, problem, _, _ = case.send("POST", "/api/v1/cameras", _camera(space, **changes))
    assert status == 422, problem
    assert problem["errors"][0]["field"] == field and reason in problem["errors"][0]["reason"]
    # The same through PATCH of a good camera.
    camera = home["cameras"][0]["id"]
    status, _, problem, _, _ = case.send("PATCH", f"/api/v1/cameras/{camera}", changes)
    assert status == 422 and problem["errors"][0]["field"] == field
    case.next_request_answered()


@pytest.mark.parametrize(
    ("polygon", "reason"),
    [
        ([[0, 0], [1, 1], [1, 0], [0, 1]], "Self-intersection"),  # a bow tie
        ([[0, 0], [1, 0], [2, 0]], "simple polygon"),  # collinear: no area
        ([[0, 0], [1, 0], [1, 1], [1, 0]], "simple polygon"),  # a spike back on itself
    ],
)
def test_a_room_polygon_must_be_simple_with_an_area(case, home, polygon, reason):
    body = {"space_id": home["space"]["id"], "name": "bad", "polygon": polygon}
    status, _, problem, _, _ = case.send("POST", "/api/v1/rooms", body)
    assert status == 422, problem
    assert problem["errors"][0]["field"] == "polygon" and reason in problem["errors"][0]["reason"]
    case.next_request_answered()


@pytest.mark.parametrize("database_url", ["sqlite", "postgresql"], indirect=True)
def test_a_camera_name_with_nul_is_refused_not_a_server_error(client, admin):
    # PostgreSQL text cannot hold NUL: the filter refuses it on every backend alike.
    got = client.get("/api/v1/cameras", params={"name": "a\x00b"}, headers=admin)
    assert got.status_code == 422, got.text
