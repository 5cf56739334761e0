"""The digital twin inside the service: the default home registered, the robot located from
its rendered marker within centimetres of the truth, frames, pause/resume/reset, and the
network calibration run against the issue's targets."""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from core.sim import default_scene, simulate_patrol
from core.sim.render import camera_model
from server.app import create_app
from tests.support.scene_recorder import SceneRecorder
from tests.support.waiting import wait_until, wait_until_unchanged


@pytest.fixture
def twin_client(make_settings):
    settings = make_settings(simulation=True, twin_rate_hz=4.0, targets_flush_hz=5.0)
    with TestClient(create_app(settings)) as client:
        yield client


def test_twin_locates_the_robot_and_is_controlled(twin_client, admin):
    client = twin_client
    cameras = client.get("/api/v1/cameras", headers=admin).json()
    assert cameras["total"] == len(default_scene().cameras)
    # The home's installed calibration (its marker drive), never the twin's true cameras.
    assert {c["status"] for c in cameras["items"]} == {"calibrated"}
    truth = {c.name: c for c in default_scene().cameras}
    for c in cameras["items"]:
        K_true = camera_model(truth[c["name"]]).K
        assert not np.allclose(c["K"], K_true, rtol=1e-6), c["name"]
        # Spec 02's calibration: focal within 1 % of the twin's.
        assert abs(c["K"][0][0] / K_true[0, 0] - 1.0) < 0.01, c["name"]
    assert client.get("/api/v1/rooms", headers=admin).json()["total"] == 3

    def robot_track():
        targets = client.get("/api/v1/targets?kind=robot", headers=admin).json()["items"]
        if not targets:
            return None
        track = client.get(f"/api/v1/targets/{targets[0]['id']}/track", headers=admin).json()
        return track if len(track["points"]) >= 5 else None

    track = wait_until(robot_track, what="the robot's track of 5 points", stalled_after_s=20)
    state = client.get("/api/v1/twin", headers=admin).json()
    assert state["enabled"] and state["running"] and state["sim_time"] > 0
    # The tracked robot against the twin's true pose at each update's own time: the marker
    # detector's ~0.1 px on cameras 3-5 m away is a few millimetres; a few cm is the bar.
    assert state["robot_error_rms_m"] < 0.03
    xy = np.array([p["xy"] for p in track["points"]])
    assert np.all(np.isfinite(xy)) and np.ptp(xy[:, 0]) > 0  # it moves
    # Track points carry their capture times on the service's clock (Unix seconds); the twin
    # maps them back to its simulated clock, and its drive is deterministic (seed 0, 0.05 s
    # steps): replaying the patrol gives the true pose at each point's time.
    t = np.array([p["t"] for p in track["points"]])
    assert abs(t.max() - time.time()) < 30
    sim = client.app.state.runtime.twin.sim_time_at(t)
    assert np.all(np.isfinite(sim))
    truth = simulate_patrol(default_scene().robot, float(sim.max()) + 0.1, dt=0.05, rng=0)
    true_xy = truth.pose[np.round(sim / 0.05).astype(int), :2]
    assert np.max(np.linalg.norm(xy - true_xy, axis=1)) < 0.03
    assert all(np.array(p["cov"]).shape == (2, 2) for p in track["points"])

    frame = client.get(
        f"/api/v1/cameras/{cameras['items'][0]['id']}/frame.jpg?overlay=true", headers=admin
    )
    assert frame.status_code == 200 and frame.headers["content-type"] == "image/jpeg"
    image = cv2.imdecode(np.frombuffer(frame.content, np.uint8), cv2.IMREAD_COLOR)
    assert image.shape == (480, 640, 3)
    missing = client.get("/api/v1/cameras/999/frame.jpg", headers=admin)
    assert missing.status_code == 404 and "not a camera of the twin" in missing.json()["detail"]

    paused = client.post("/api/v1/twin/pause", headers=admin).json()
    assert paused["paused"] and not paused["running"]
    # The step under way ends: the simulated time stands (two reads more than a step apart).
    t0 = wait_until_unchanged(
        lambda: client.get("/api/v1/twin", headers=admin).json()["sim_time"],
        what="the paused twin's simulated time",
        interval_s=0.3,
        stalled_after_s=5,
    )
    time.sleep(0.5)  # time must pass: the paused twin does not advance in it
    assert client.get("/api/v1/twin", headers=admin).json()["sim_time"] == t0
    reset = client.post("/api/v1/twin/reset", headers=admin).json()
    assert reset["sim_time"] == 0
    resumed = client.post("/api/v1/twin/resume", headers=admin).json()
    assert resumed["running"]
    wait_until(
        lambda: client.get("/api/v1/twin", headers=admin).json()["sim_time"] > 0,
        what="the resumed twin's simulated time",
        stalled_after_s=20,
    )
    rate = client.post("/api/v1/twin/rate", json={"rate_hz": 2}, headers=admin).json()
    assert rate["rate_hz"] == 2
    assert client.post("/api/v1/twin/rate", json={"rate_hz": 0}, headers=admin).status_code == 422

    names = [s["name"] for s in client.get("/api/v1/twin/scenarios", headers=admin).json()]
    assert "network-calibration" in names

    # After the reset the robot's track forms again and the stream shows it.
    deadline = time.monotonic() + 20
    with client.websocket_connect(
        "/api/v1/ws/targets", headers={"Authorization": "Bearer test-admin-token"}
    ) as ws:
        while time.monotonic() < deadline:
            message = ws.receive_json()
            if "robot" in {t["kind"] for t in message["targets"]}:
                break
    assert message["type"] == "positions"
    assert "robot" in {t["kind"] for t in message["targets"]}


def test_twin_endpoints_without_the_twin(client, admin):
    assert client.get("/api/v1/twin", headers=admin).json()["enabled"] is False
    assert client.post("/api/v1/twin/pause", headers=admin).status_code == 409
    response = client.get("/api/v1/cameras/1/frame.jpg", headers=admin)
    assert response.status_code == 404 and "twin is not running" in response.json()["detail"]
    assert client.post("/api/v1/twin/reset").status_code == 401


# The drive is the same on either database; its storage and apply paths run on PostgreSQL in
# tests/server/api/test_api_calibration.py.
@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_network_run_calibrates_every_twin_camera_and_apply_updates_them(
    twin_client, admin, run_waiter
):
    client = twin_client
    client.post("/api/v1/twin/pause", headers=admin)  # the drive renders on its own
    submitted = client.post(
        "/api/v1/calibration-runs",
        json={"kind": "network", "options": {"seed": 3, "target": "marker"}},
        headers=admin,
    )
    assert submitted.status_code == 202, submitted.text
    assert submitted.json()["source"] == "twin"
    # Its longest stage without a progress report is the drive (~25 s of CPU; over 240 s on
    # two cores shared by ~35 busy processes): 600 s without a change is a run that stopped,
    # not a busy machine (tests/browser/test_floor.py measured it).
    run = run_waiter(client, submitted.json()["id"], stalled_after_s=600)
    assert run["status"] == "succeeded", run["error"]
    result = run["result"]
    assert result["kind"] == "network" and not result["rejected"]
    cameras = {c["id"]: c for c in client.get("/api/v1/cameras", headers=admin).json()["items"]}
    assert {c["camera_id"] for c in result["cameras"]} == set(cameras)
    for cam in result["cameras"]:
        # Nothing of the twin's truth enters the estimate (intrinsics from each camera's own
        # chessboard, poses from the odometry, the world frame from the signposts the robot
        # reads). The errors must be those of an efficient estimator: within 3.5 times the
        # bound of the start pose's frame the signposts free them from (spec 02's goal of
        # 2 cm and 0.3 deg is asserted on an untuned seed in tests/core/sim/test_scenarios.py).
        # The focal length meets the 1 % goal outright.
        errors, bound = cam["errors"], cam["bound"]
        assert abs(errors["focal_pct"]) < 1.0, cam
        assert errors["position_m"] < 3.5 * bound["position_m"], cam
        assert errors["rotation_deg"] < 3.5 * bound["rotation_deg"], cam
        assert cam["poses_seen"] >= 8 and cam["std"]["f_px"] > 0

    applied = client.post(f"/api/v1/calibration-runs/{run['id']}/apply", headers=admin)
    assert applied.status_code == 200, applied.text
    assert len(applied.json()) == len(default_scene().cameras)
    for cam in result["cameras"]:
        camera = client.get(f"/api/v1/cameras/{cam['camera_id']}", headers=admin).json()
        assert camera["status"] == "calibrated" and camera["calibration_run_id"] == run["id"]
        assert np.allclose(camera["K"], cam["K"])
        assert np.allclose(camera["T_world_camera"], cam["T_world_camera"])
        history = client.get(
            f"/api/v1/cameras/{cam['camera_id']}/calibrations", headers=admin
        ).json()
        # The installed calibration the twin registered, then this run, newest first.
        assert history["total"] == 2 and history["items"][0]["calibration_run_id"] == run["id"]


def test_network_run_needs_the_twin(client, admin):
    response = client.post("/api/v1/calibration-runs", json={"kind": "network"}, headers=admin)
    assert response.status_code == 409 and "INTSPACE_SIMULATION" in response.json()["detail"]
    bad = {"kind": "network", "options": {"target": "board"}}
    assert client.post("/api/v1/calibration-runs", json=bad, headers=admin).status_code == 422
    # The drive's length is refused by name before anything is planned: more than 0 and at
    # most 30 minutes.
    for minutes in (0, -1, 31, 1e9):
        bad = {"kind": "network", "options": {"minutes": minutes}}
        response = client.post("/api/v1/calibration-runs", json=bad, headers=admin)
        assert response.status_code == 422, response.text
        assert response.json()["errors"][0]["field"].endswith("minutes"), response.text


def test_twin_pushes_agents_tracks_and_images_to_the_scene(twin_client, admin):
    recorder = SceneRecorder(answer=True)
    twin_client.app.state.runtime.scene_sync.scene = recorder

    def pushed():
        return {"upsert_agent", "set_track", "set_camera_image"} <= set(recorder.calls)

    wait_until(pushed, what="agents, tracks and images pushed to the scene", stalled_after_s=20)
    agents = {args[0]["id"]: args[0] for args in recorder.calls["upsert_agent"]}
    assert agents["robot"]["kind"] == "robot" and "theta" in agents["robot"]
    assert any(a["kind"] == "person" for a in agents.values())
    robot_tracks = [args for args in recorder.calls["set_track"] if args[0] == "robot"]
    assert robot_tracks and all(len(p) == 2 for p in robot_tracks[-1][1])
    assert np.array(robot_tracks[-1][2]).shape == (2, 2)  # the newest point's covariance
    camera_id, image = recorder.calls["set_camera_image"][0]
    assert camera_id in twin_client.app.state.runtime.twin.camera_ids.values()
    assert image.shape == (480, 640, 3)
