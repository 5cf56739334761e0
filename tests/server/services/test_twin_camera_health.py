"""The digital twin's cameras report their health as camera nodes do: online while their frames
come, stalled while the twin is paused, with the frame rate, skipped frames and the newest
frame's time; a camera nobody reports on stays offline. The twin's projector and printed
landmarks enter the registry with its home, once."""

from __future__ import annotations

import time

import numpy as np
import pytest
from fastapi.testclient import TestClient

from core.sim import default_scene
from server.app import create_app
from server.services.camera_health import STALLED_AFTER_S
from server.services.twin_home import bootstrap_space, register_devices
from tests.support.waiting import wait_until

RATE_HZ = 4.0


@pytest.fixture
def twin_client(make_settings):
    settings = make_settings(simulation=True, twin_rate_hz=RATE_HZ)
    with TestClient(create_app(settings)) as client:
        yield client


# The health book lives in memory: the database backend has no part in it (the registry reads
# around it are tested on both).
@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_twin_cameras_report_their_health(twin_client, admin):
    client = twin_client
    names = {c.name for c in default_scene().cameras}
    space = client.get("/api/v1/spaces", headers=admin).json()["items"][0]["id"]
    other = client.post("/api/v1/spaces", json={"name": "flat"}, headers=admin).json()["id"]
    body = {"name": "hall", "width": 640, "height": 480, "space_id": other}
    foreign = client.post("/api/v1/cameras", json=body, headers=admin).json()["id"]

    def twin_health():
        items = client.get(f"/api/v1/cameras?space_id={space}", headers=admin).json()["items"]
        return items if all(c["health"]["status"] == "online" for c in items) else None

    cameras = wait_until(twin_health, what="the twin's cameras online", stalled_after_s=30)
    assert {c["name"] for c in cameras} == names

    # The frame rate over a wall-clock window of 10 of the twin's own steps (2.5 s at the set
    # rate): every step publishes one frame of every camera.
    def steps() -> int:
        return client.get("/api/v1/twin", headers=admin).json()["steps"]

    t0, steps0 = time.time(), steps()
    steps1 = wait_until(
        lambda: (n := steps()) >= steps0 + 10 and n,
        what="10 steps of the twin",
        stalled_after_s=10,
        progress=steps,
    )
    t1 = time.time()
    counted = (steps1 - steps0) / (t1 - t0)
    now = time.time()
    for camera in client.get(f"/api/v1/cameras?space_id={space}", headers=admin).json()["items"]:
        health = camera["health"]
        assert health["status"] == "online", camera["name"]
        assert health["since"] is not None and health["since"] <= now
        # The twin keeps the service's clock; its cameras are rendered, never reconnected.
        assert health["clock_offset_s"] == 0.0
        assert health["stalls"] == 0 and health["reconnects"] == 0 and health["dropped"] >= 0
        # The newest frame is at most a few frame periods old (a loaded machine renders late).
        assert now - 2.0 < health["last_frame_t"] <= now
        # fps is measured over the last 10 frames, the count over 10 steps: both near the set rate
        # and never above it by more than the stamps' jitter (5 %); a loaded machine renders
        # fewer frames, so the two agree to 40 % of the set rate.
        assert 0.0 < health["fps"] <= RATE_HZ * 1.05
        assert abs(health["fps"] - counted) < 0.4 * RATE_HZ, (health["fps"], counted)
        one = client.get(f"/api/v1/cameras/{camera['id']}", headers=admin).json()["health"]
        assert one["status"] == "online" and one["since"] == health["since"]

    # Paused, the twin still reports but delivers no frame: stalled from the last frame plus
    # the quiet time (2 s, or two frame periods if longer).
    last = max(c["health"]["last_frame_t"] for c in cameras)
    assert client.post("/api/v1/twin/pause", headers=admin).status_code == 200
    camera_id = cameras[0]["id"]

    def stalled():
        health = client.get(f"/api/v1/cameras/{camera_id}", headers=admin).json()["health"]
        return health if health["status"] == "stalled" else None

    health = wait_until(stalled, what="the paused twin's camera stalled", stalled_after_s=10)
    quiet = max(STALLED_AFTER_S, 2.0 / health["fps"])
    assert health["since"] == pytest.approx(health["last_frame_t"] + quiet)
    assert health["last_frame_t"] >= last
    # Resumed: online again, since the first frame after the pause.
    paused_at = time.time()
    assert client.post("/api/v1/twin/resume", headers=admin).status_code == 200

    def online():
        health = client.get(f"/api/v1/cameras/{camera_id}", headers=admin).json()["health"]
        return health if health["status"] == "online" else None

    back = wait_until(online, what="the resumed twin's camera online", stalled_after_s=10)
    assert back["since"] >= paused_at

    # A camera of another space that no node reports on: offline, never seen.
    health = client.get(f"/api/v1/cameras/{foreign}", headers=admin).json()["health"]
    assert health == {**health, "status": "offline", "since": None, "fps": None}


def test_twin_registers_its_projector_and_landmarks_once(client, admin):
    scene = default_scene()
    with client.app.state.runtime.session_factory() as session:
        space, _ = bootstrap_space(session, scene)
        register_devices(session, space, scene)
    projectors = client.get(f"/api/v1/projectors?space_id={space}", headers=admin).json()
    (projector,) = projectors["items"]
    # Entered as an installer knows it: uncalibrated, its mount found by a calibration run.
    assert projector["name"] == scene.projector.name and projector["T_world_projector"] is None
    landmarks = client.get(f"/api/v1/landmarks?space_id={space}", headers=admin).json()["items"]
    assert sorted(lm["payload"] for lm in landmarks) == sorted(lm.payload for lm in scene.landmarks)
    sizes = {lm.payload: lm.size for lm in scene.landmarks}
    assert all(lm["size_m"] == sizes[lm["payload"]] for lm in landmarks)
    # No world pose: that is the twin's truth, which the survey measures.
    assert all(lm["kind"] == "qr" and lm["T_world_landmark"] is None for lm in landmarks)

    # A second start adds nothing and keeps what a user changed.
    moved = np.eye(4)
    moved[:3, 3] = [1.0, 2.0, 0.9]
    body = {"T_world_landmark": moved.tolist()}
    lm_id = landmarks[0]["id"]
    assert client.patch(f"/api/v1/landmarks/{lm_id}", json=body, headers=admin).status_code == 200
    with client.app.state.runtime.session_factory() as session:
        assert bootstrap_space(session, scene)[0] == space
        register_devices(session, space, scene)
    assert client.get("/api/v1/projectors", headers=admin).json()["total"] == 1
    again = client.get(f"/api/v1/landmarks?space_id={space}", headers=admin).json()
    assert again["total"] == len(scene.landmarks)
    kept = client.get(f"/api/v1/landmarks/{lm_id}", headers=admin).json()
    assert np.allclose(kept["T_world_landmark"], moved)
