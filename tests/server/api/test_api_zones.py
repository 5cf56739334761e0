"""Zones through the API: validation (vertices, simple polygon, slug taken -> 409), rooms listed
read-only, and a zone's live occupancy from the tracker fed with observations of one person who
walks into it (the true position is the observations' projection source)."""

from __future__ import annotations

import time

import pytest

from tests.support.waiting import wait_until
from tests.support.walking_person import register_corner_cameras, walk

SOFA = [[0.0, 0.0], [2.0, 0.0], [2.0, 3.0], [0.0, 3.0]]


def _space(client, admin) -> int:
    response = client.post("/api/v1/spaces", json={"name": "Flat"}, headers=admin)
    assert response.status_code == 201, response.text
    return response.json()["id"]


def test_zone_crud_validation_and_rooms(client, admin):
    sid = _space(client, admin)
    room = {"space_id": sid, "name": "Living room", "polygon": [[0, 0], [5, 0], [5, 4], [0, 4]]}
    assert client.post("/api/v1/rooms", json=room, headers=admin).status_code == 201
    url = f"/api/v1/spaces/{sid}/zones"
    body = {"name": "Sofa corner", "polygon": SOFA, "inertia_s": 2.0, "loiter_s": 30}
    response = client.post(url, json=body, headers=admin)
    assert response.status_code == 201, response.text
    zone = response.json()
    assert zone["slug"] == "sofa-corner" and zone["occupancy"] == 0 and not zone["read_only"]
    assert zone["inertia_s"] == 2.0 and zone["loiter_s"] == 30

    bad = [
        ({**body, "name": "x", "polygon": [[0, 0], [1, 0]]}, 422, "polygon"),
        ({**body, "name": "x", "polygon": [[0, 0], [1, 1], [1, 0], [0, 1]]}, 422, "simple"),
        ({**body, "name": "SOFA  corner!"}, 409, "sofa-corner"),
        ({**body, "name": "living_room"}, 409, "room"),
        ({**body, "name": "!!!"}, 422, "letter"),
        ({**body, "name": "y", "inertia_s": -1}, 422, "inertia_s"),
    ]
    for payload, code, word in bad:
        response = client.post(url, json=payload, headers=admin)
        assert response.status_code == code, (payload, response.text)
        assert word in response.text
    assert client.post("/api/v1/spaces/999/zones", json=body, headers=admin).status_code == 404
    assert client.post(url, json=body).status_code == 401

    listed = client.get(url, headers=admin).json()
    assert [(z["slug"], z["read_only"]) for z in listed] == [
        ("living-room", True),
        ("sofa-corner", False),
    ]
    assert listed[0]["inertia_s"] == 1.0 and listed[0]["room_id"] is not None

    zid = zone["id"]
    response = client.patch(f"/api/v1/zones/{zid}", json={"name": "Reading"}, headers=admin)
    assert response.status_code == 200 and response.json()["slug"] == "reading"
    response = client.patch(f"/api/v1/zones/{zid}", json={"loiter_s": None}, headers=admin)
    assert response.status_code == 422
    assert client.get(f"/api/v1/zones/{zid}", headers=admin).json()["name"] == "Reading"
    assert client.delete(f"/api/v1/zones/{zid}", headers=admin).status_code == 204
    assert client.get(f"/api/v1/zones/{zid}", headers=admin).status_code == 404
    assert [z["slug"] for z in client.get(url, headers=admin).json()] == ["living-room"]
    for bad_id in (0, 2**31):
        assert client.get(f"/api/v1/zones/{bad_id}", headers=admin).status_code == 422


# Real time (10 s): on SQLite only; the zones' storage runs on both backends above.
@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_occupancy_follows_a_person_walking_in(client, admin):
    sid = _space(client, admin)
    ids, cams = register_corner_cameras(client, admin, sid, "cam")
    url = f"/api/v1/spaces/{sid}/zones"
    zone = client.post(url, json={"name": "sofa", "polygon": SOFA, "inertia_s": 0.5}, headers=admin)
    assert zone.status_code == 201
    # A person walks from x = 3.5 (outside) to x = 1.0 (inside) over 2.5 s, then stands for
    # 1.5 s, seen by the three cameras at 10 Hz with 0.5 px noise; its axis point at 1 m.
    occupancy = []

    def read_occupancy() -> int:
        occupancy.append(client.get(url, headers=admin).json()[0]["occupancy"])
        return occupancy[-1]

    path = [(max(1.0, 3.5 - k * 0.1), 1.5) for k in range(40)]
    walk(client, admin, ids, cams, path, t0=time.time() - 0.1, after_each=read_occupancy)
    # The tracker releases frames within its latency (1 s): by then the person has been inside
    # (x < 2 from k = 16) for more than the inertia: counted once, never twice.
    wait_until(
        lambda: occupancy[-1] == 1 or read_occupancy() == 1,
        what="the zone occupied",
        stalled_after_s=3,
    )
    assert max(occupancy) == 1 and occupancy[0] == 0
    # Ends after the tracker's end_after without detections: the zone empties.
    wait_until(
        lambda: occupancy[-1] == 0 or read_occupancy() == 0,
        what="the zone empty again",
        stalled_after_s=10,
        poll_s=0.2,
    )
