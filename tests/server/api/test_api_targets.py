"""Localisation through the API: batched observations stored and tracked, labelled groups fused
on the floor against projections of known cameras, refusals of unusable cameras and malformed
bodies, targets with their life cycle, tracks and the stream."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
from starlette.websockets import WebSocketDisconnect

from core.localization import NetworkCamera
from tests.support.cameras import register_cameras
from tests.support.tracker_clock import HeldClock, wait_processed

K = [[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]]
DIST = [-0.1, 0.01, 0.0005, -0.0003, 0.0]


def _cameras() -> list[NetworkCamera]:
    return [
        NetworkCamera.looking_at(K, DIST, pos, look, (640, 480))
        for pos, look in (
            ([0.0, 0.0, 2.8], [2.0, 1.5, 0.0]),
            ([4.0, 3.0, 2.8], [2.0, 1.5, 0.0]),
            ([4.0, 0.0, 2.8], [2.0, 1.5, 0.0]),
        )
    ]


def test_observations_fuse_to_the_true_positions(client, admin):
    cameras = _cameras()
    ids = register_cameras(client, admin, cameras)
    rng = np.random.default_rng(1)
    truth = rng.uniform([1.0, 0.5], [3.0, 2.5], (20, 2))
    height = 0.36
    now = time.time()
    observations = []
    for j, xy in enumerate(truth):
        X = np.array([[xy[0], xy[1], height]])
        for cid, cam in zip(ids, cameras, strict=True):
            observations.append(
                {
                    "camera_id": cid,
                    "t": now,
                    "pixel": cam.project(X)[0].tolist(),
                    "sigma_px": 0.5,
                    "target": f"t{j}",
                    "height": height,
                }
            )
    response = client.post(
        "/api/v1/observations", json={"observations": observations}, headers=admin
    )
    assert response.status_code == 200, response.text
    assert response.json()["stored"] == 60 and response.json()["frames"] == 3
    positions = response.json()["positions"]
    assert [p["target"] for p in positions] == [f"t{j}" for j in range(20)]
    xy = np.array([p["xy"] for p in positions])
    # Exact projections: the ML estimate is the true point up to the LM's stopping tolerance.
    assert np.max(np.abs(xy - truth)) < 1e-9
    for p in positions:
        cov = np.array(p["cov"])
        assert p["n_cameras"] == 3 and p["estimator"] == "ml" and p["status"] == "ok"
        assert cov.shape == (2, 2) and np.all(np.linalg.eigvalsh(cov) > 0)
        # 0.5 px at ~3 m with f = 500 px is a few mm: the covariance says so.
        assert 1e-4 < np.sqrt(np.trace(cov)) < 1e-2

    # The labelled detections become targets through the tracker (written by the throttled
    # writer), each at the tracker's estimate from its three cameras. Seen once, they coast
    # and end within a second or two, so the history lists them (state=all).
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:
        listed = client.get("/api/v1/targets?state=all", headers=admin).json()
        if listed["total"] == 20:
            break
        time.sleep(0.1)
    assert listed["total"] == 20
    by_label = {t["label"]: t for t in listed["items"]}
    for j, xy in enumerate(truth):
        target = by_label[f"t{j}"]
        assert target["state"] in ("confirmed", "coasting", "ended")
        assert target["first_seen"] == pytest.approx(now)
        # Exact pixels through three sequential EKF updates: within a millimetre of the truth.
        assert np.linalg.norm(np.array(target["xy"]) - xy) < 1e-3
    first = listed["items"][0]
    track = client.get(f"/api/v1/targets/{first['id']}/track", headers=admin).json()
    assert len(track["points"]) == 1
    assert np.allclose(track["points"][0]["xy"], first["xy"])
    assert client.get("/api/v1/targets/999/track", headers=admin).status_code == 404


def test_one_camera_gives_a_monocular_position_and_unposed_cameras_are_refused(client, admin):
    cameras = _cameras()
    ids = register_cameras(client, admin, cameras[:1])
    X = np.array([[2.0, 1.0, 0.0]])
    px = cameras[0].project(X)[0].tolist()
    body = {"observations": [{"camera_id": ids[0], "t": 1, "pixel": px, "target": "a"}]}
    response = client.post("/api/v1/observations", json=body, headers=admin)
    assert response.status_code == 200, response.text
    assert np.allclose(response.json()["positions"][0]["xy"], [2.0, 1.0], atol=1e-9)

    bare = client.post(
        "/api/v1/cameras", json={"name": "bare", "width": 640, "height": 480}, headers=admin
    ).json()["id"]
    body["observations"].append({"camera_id": bare, "t": 1, "pixel": [1, 2]})
    response = client.post("/api/v1/observations", json=body, headers=admin)
    assert response.status_code == 422
    problem = response.json()
    assert problem["errors"][0]["field"] == "observations.1.camera_id"
    assert f"camera {bare}" in problem["detail"] and "intrinsics" in problem["detail"]


@pytest.mark.parametrize(
    "body",
    [
        {},
        {"observations": []},
        {"observations": [{"camera_id": 1, "t": 0, "pixel": [1]}]},
        {"observations": [{"camera_id": 1, "t": 0, "pixel": [1, "x"]}]},
        {"observations": [{"camera_id": 1, "t": 0, "pixel": [1, 2], "cov": [[1, 2], [3, 1]]}]},
        {"observations": [{"camera_id": 1, "t": 0, "pixel": [1, 2], "sigma_px": -1}]},
        {"observations": [{"camera_id": 0, "t": 0, "pixel": [1, 2]}]},
        {"observations": [{"camera_id": 999, "t": 0, "pixel": [1, 2]}]},
    ],
)
def test_malformed_observations_are_4xx(client, admin, body):
    response = client.post("/api/v1/observations", json=body, headers=admin)
    assert 400 <= response.status_code < 500, response.text
    assert response.headers["content-type"] == "application/problem+json"


def test_observations_need_a_token(client):
    response = client.post("/api/v1/observations", json={"observations": []})
    assert response.status_code == 401


def test_stream_sends_positions_and_refuses_a_bad_token(client, admin):
    cameras = _cameras()
    ids = register_cameras(client, admin, cameras)
    X = np.array([[2.0, 1.5, 0.0]])
    now = time.time()
    body = {
        "observations": [
            {"camera_id": cid, "t": now, "pixel": cam.project(X)[0].tolist(), "target": "cup"}
            for cid, cam in zip(ids, cameras, strict=True)
        ]
    }
    assert client.post("/api/v1/observations", json=body, headers=admin).status_code == 200
    deadline = time.monotonic() + 5
    with client.websocket_connect(
        "/api/v1/ws/targets", headers={"Authorization": "Bearer test-admin-token"}
    ) as ws:
        while time.monotonic() < deadline:
            message = ws.receive_json()
            if message["targets"]:
                break
    assert message["type"] == "positions" and message["t"] == pytest.approx(now)
    (target,) = message["targets"]
    assert target["label"] == "cup" and target["kind"] == "unknown"
    assert target["state"] in ("confirmed", "coasting")
    assert np.linalg.norm(np.array(target["xy"]) - [2.0, 1.5]) < 1e-3

    with pytest.raises(WebSocketDisconnect) as info:
        with client.websocket_connect(
            "/api/v1/ws/targets", headers={"Authorization": "Bearer wrong"}
        ) as ws:
            ws.receive_json()
    assert info.value.code == 1008


def test_targets_live_by_default_newest_first_and_tracks_page_back(client, admin):
    """A target seen for a while, then silent: live while it is tracked, ended afterwards (only
    in state=all); its stored track pages back with `until`."""
    cameras = _cameras()
    ids = register_cameras(client, admin, cameras)
    now = time.time()
    for _ in range(30):  # a walker at 0.4 m/s, stamped as a live camera would stamp it
        time.sleep(0.02)
        t = time.time()
        X = np.array([[1.5 + 0.4 * (t - now), 1.5, 1.0]])
        body = {
            "observations": [
                {
                    "camera_id": cid,
                    "t": t,
                    "pixel": cam.project(X)[0].tolist(),
                    "kind": "person",
                    "height": 1.0,
                    "sigma_px": 0.5,
                }
                for cid, cam in zip(ids, cameras, strict=True)
            ]
        }
        assert client.post("/api/v1/observations", json=body, headers=admin).status_code == 200
    deadline = time.monotonic() + 5
    live = []
    while time.monotonic() < deadline and not live:
        live = client.get("/api/v1/targets", headers=admin).json()["items"]
        time.sleep(0.05)
    (target,) = live
    assert target["kind"] == "person" and target["state"] in ("confirmed", "coasting")
    assert target["first_seen"] >= now and target["last_seen"] > target["first_seen"]
    # The tracker's rate is kept (at most track_points_hz points a second are stored).
    client.app.state.runtime.targets.flush()
    track = client.get(f"/api/v1/targets/{target['id']}/track", headers=admin).json()["points"]
    assert len(track) >= 6
    older = client.get(
        f"/api/v1/targets/{target['id']}/track?limit=3&until={track[5]['t']}", headers=admin
    ).json()["points"]
    assert [p["t"] for p in older] == [p["t"] for p in track[2:5]]
    # Silence: the target ends and leaves the live list, the history keeps it.
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        if not client.get("/api/v1/targets", headers=admin).json()["items"]:
            break
        time.sleep(0.1)
    assert client.get("/api/v1/targets", headers=admin).json()["items"] == []
    client.app.state.runtime.targets.flush()
    history = client.get("/api/v1/targets?state=all", headers=admin).json()["items"]
    assert [t["state"] for t in history] == ["ended"]
    recent = client.get("/api/v1/targets/tracks?state=all", headers=admin).json()["tracks"]
    whole = client.get(f"/api/v1/targets/{target['id']}/track", headers=admin).json()["points"]
    assert recent[0]["target_id"] == target["id"]
    assert [p[0] for p in recent[0]["points"]] == [p["t"] for p in whole]


# -- frames in which nothing was detected -------------------------------------------------------


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_empty_frames_release_the_other_cameras_frames_at_once(client, admin):
    """A camera that saw nothing says so: the tracker need not wait its reorder window (1 s by
    default) for that camera before taking the other cameras' frames of the same time."""
    cameras = _cameras()[:2]
    a, b = register_cameras(client, admin, cameras)
    tracking = client.app.state.runtime.tracking
    assert tracking.latency == 1.0  # the default window; the clock below never reaches it
    T = float(np.ceil(time.time())) + 10.0
    clock = HeldClock(T)
    tracking._clock = clock
    X = np.array([[2.0, 1.5, 0.0]])
    px = cameras[0].project(X)[0].tolist()

    def post(body: dict) -> dict:
        response = client.post("/api/v1/observations", json=body, headers=admin)
        assert response.status_code == 200, response.text
        return response.json()

    base = tracking.frames_processed
    # Both cameras heard from at T - 0.5: camera a saw the cup, camera b nothing.
    first = post(
        {
            "observations": [{"camera_id": a, "t": T - 0.5, "pixel": px, "target": "cup"}],
            "empty_frames": [{"camera_id": b, "t": T - 0.5}],
        }
    )
    assert (first["stored"], first["frames"], first["late"]) == (1, 2, 0)
    wait_processed(tracking, base + 2)
    # Camera a's next frame waits for camera b, which may still send a frame as old ...
    post({"observations": [{"camera_id": a, "t": T - 0.1, "pixel": px, "target": "cup"}]})
    # Time must pass: nothing is taken in a window of 15 wake-ups of the tracker thread (every
    # 20 ms) while the service's clock stands still.
    time.sleep(0.3)
    assert tracking.frames_processed == base + 2
    # ... until camera b says it saw nothing then: both are taken at once, well inside the
    # window (the clock has not moved: the release is the watermark's, not the window's end).
    empty = post({"empty_frames": [{"camera_id": b, "t": T - 0.1}]})
    assert (empty["stored"], empty["frames"], empty["late"], empty["positions"]) == (0, 1, 0, [])
    wait_processed(tracking, base + 4)
    state, t, xy = client.app.state.runtime.targets.latest("cup")
    assert state == "confirmed"
    assert t == T - 0.1 and np.linalg.norm(np.array(xy) - [2.0, 1.5]) < 1e-3
    # The stream says each target's own time.
    with client.websocket_connect("/api/v1/ws/targets", headers=admin) as ws:
        message = ws.receive_json()
    (target,) = message["targets"]
    assert target["t"] == message["t"] == T - 0.1 and target["label"] == "cup"
    # An empty frame older than what the tracker took is late, as a detection would be.
    assert post({"empty_frames": [{"camera_id": b, "t": T - 0.2}]})["late"] == 1
    assert client.get("/api/v1/targets?state=all", headers=admin).json()["total"] <= 1


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_empty_frames_are_validated_like_detections(client, admin):
    cameras = _cameras()[:2]
    a, b = register_cameras(client, admin, cameras)
    bare = client.post(
        "/api/v1/cameras", json={"name": "bare", "width": 640, "height": 480}, headers=admin
    ).json()["id"]
    px = cameras[0].project(np.array([[2.0, 1.5, 0.0]]))[0].tolist()
    now = time.time()
    cases = [
        ({"empty_frames": []}, 422, None),
        ({"empty_frames": [{"camera_id": a}]}, 422, None),
        ({"empty_frames": [{"camera_id": a, "t": "nan"}]}, 422, None),
        ({"empty_frames": [{"camera_id": 0, "t": now}]}, 422, None),
        ({"empty_frames": [{"camera_id": a, "t": now, "pixel": [1, 2]}]}, 422, None),
        ({"empty_frames": [{"camera_id": 999, "t": now}]}, 422, "empty_frames.0.camera_id"),
        ({"empty_frames": [{"camera_id": bare, "t": now}]}, 422, "empty_frames.0.camera_id"),
        (
            {"empty_frames": [{"camera_id": a, "t": now}, {"camera_id": a, "t": now}]},
            422,
            "empty_frames.1",
        ),
        (
            {
                "observations": [{"camera_id": a, "t": now, "pixel": px}],
                "empty_frames": [{"camera_id": b, "t": now}, {"camera_id": a, "t": now}],
            },
            422,
            "empty_frames.1",
        ),
    ]
    for body, code, field in cases:
        response = client.post("/api/v1/observations", json=body, headers=admin)
        assert response.status_code == code, (body, response.text)
        assert response.headers["content-type"] == "application/problem+json"
        if field is not None:
            assert response.json()["errors"][0]["field"] == field, response.text
    # Nothing of the refused batches reached the tracker or the database.
    assert client.app.state.runtime.tracking.frames_processed == 0
    # An ingest token speaks for its own cameras' empty frames only.
    token = client.post(
        "/api/v1/tokens",
        json={"name": "node", "scopes": ["ingest"], "camera_ids": [a]},
        headers=admin,
    ).json()["token"]
    node = {"Authorization": f"Bearer {token}"}
    mine = {"observations": [], "empty_frames": [{"camera_id": a, "t": now}]}
    assert client.post("/api/v1/observations", json=mine, headers=node).status_code == 200
    other = {"observations": [], "empty_frames": [{"camera_id": b, "t": now}]}
    response = client.post("/api/v1/observations", json=other, headers=node)
    assert response.status_code == 403
    assert f"not [{b}]" in response.json()["detail"], response.text


def test_empty_frames_travel_to_the_process_that_tracks_their_space():
    """Where another process tracks the space, a camera frame travels as itself with its
    stored rows' ids, and an empty frame as (camera, time), on the same channel and in one
    message; the receiver rebuilds the very frame (no database read); a frame too large for
    one notification travels by its rows' ids."""
    from server.services.tracking import (
        DETECTIONS_CHANNEL,
        CameraFrame,
        TrackingService,
        empty_frame,
    )
    from server.services.tracking.wire import frame_of_item

    class Locks:  # no space's lock is ever free: another process tracks them all
        def poll(self, spaces):
            return set(), set()

    class Fanout:
        def __init__(self) -> None:
            self.sent: list = []

        def publish(self, channel, base, items) -> int:
            self.sent.append((channel, base, list(items)))
            return 1

    service = TrackingService(None, None)  # type: ignore[arg-type]
    service._locks, service._fanout = Locks(), Fanout()  # type: ignore[assignment]
    rng = np.random.default_rng(5)
    seen = CameraFrame(
        3,
        1_700_000_012.123456789,
        rng.uniform(0.0, 640.0, (2, 2)),
        np.array([[[0.49, 0.013], [0.013, 0.36]], [[2.25, -0.4], [-0.4, 1.21]]]),
        np.array([1.0, 0.1]),
        ["person", "robot"],
        [None, "r1"],
        ids=(7, 8),
        appearances=rng.dirichlet(np.ones(64), 2),
    )
    late = service.submit([seen, empty_frame(4, 12.5)], {3: 1, 4: 1})
    assert late == 0
    ((channel, base, items),) = service._fanout.sent
    assert (channel, base) == (DETECTIONS_CHANNEL, {"space": 1})
    assert items[1] == {"c": 4, "t": 12.5}
    # Through JSON, as a notification carries it: every number comes back exactly.
    got = frame_of_item(json.loads(json.dumps(items[0])))
    assert (got.camera_id, got.t, got.ids) == (3, seen.t, (7, 8))
    assert (got.kinds, got.labels) == (["person", "robot"], [None, "r1"])
    for name in ("pixels", "cov", "heights", "appearances"):
        assert np.array_equal(getattr(got, name), getattr(seen, name)), name
    assert frame_of_item(items[1]).pixels.shape == (0, 2)
    assert frame_of_item(items[1]).appearances is None
    # A frame of 200 detections exceeds a notification: its 200 rows go by their ids.
    crowd = CameraFrame(
        3,
        13.0,
        rng.uniform(0.0, 640.0, (200, 2)),
        np.tile(np.eye(2), (200, 1, 1)),
        np.ones(200),
        ["person"] * 200,
        [None] * 200,
        ids=tuple(range(100, 300)),
    )
    service._fanout.sent.clear()
    assert service.submit([crowd], {3: 1}) == 0
    assert service._fanout.sent == [(DETECTIONS_CHANNEL, {"space": 1}, [[100, 299]])]


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_a_notified_empty_frame_moves_the_tracker_on(client, admin):
    """The tracking process takes an empty frame another process received (its notification)
    as if it had been posted to it."""
    cameras = _cameras()[:2]
    a, b = register_cameras(client, admin, cameras)
    tracking = client.app.state.runtime.tracking
    T = float(np.ceil(time.time())) + 10.0
    tracking._clock = HeldClock(T)
    px = cameras[0].project(np.array([[2.0, 1.5, 0.0]]))[0].tolist()
    base = tracking.frames_processed
    body = {
        "observations": [{"camera_id": a, "t": T - 0.5, "pixel": px, "target": "cup"}],
        "empty_frames": [{"camera_id": b, "t": T - 0.5}],
    }
    assert client.post("/api/v1/observations", json=body, headers=admin).status_code == 200
    wait_processed(tracking, base + 2)
    body = {"observations": [{"camera_id": a, "t": T - 0.1, "pixel": px, "target": "cup"}]}
    assert client.post("/api/v1/observations", json=body, headers=admin).status_code == 200
    time.sleep(0.2)  # time must pass: nothing is taken in 10 wake-ups of the tracker thread
    assert tracking.frames_processed == base + 2  # camera a's frame waits for camera b
    tracking._on_detections({"space": None, "items": [{"c": b, "t": T - 0.1}]})
    tracking._read_notified()
    wait_processed(tracking, base + 4)
    assert client.app.state.runtime.targets.latest("cup")[1] == T - 0.1


def test_targets_tracks_and_stream_of_one_space(client, admin):
    """Two spaces, one target in each: every read of targets keeps to the space asked for."""
    cameras = _cameras()
    spaces = [
        client.post("/api/v1/spaces", json={"name": name}, headers=admin).json()["id"]
        for name in ("home", "flat")
    ]
    now = time.time()
    for space, label, xy in zip(spaces, ("a", "b"), ([2.0, 1.5], [1.0, 2.0]), strict=True):
        body = {
            "name": f"cam-{space}",
            "width": 640,
            "height": 480,
            "K": K,
            "dist": DIST,
            "T_world_camera": cameras[0].T_world_camera.tolist(),
            "space_id": space,
        }
        cid = client.post("/api/v1/cameras", json=body, headers=admin).json()["id"]
        pixel = cameras[0].project(np.array([[*xy, 0.0]]))[0].tolist()
        obs = {"camera_id": cid, "t": now, "pixel": pixel, "target": label}
        response = client.post("/api/v1/observations", json={"observations": [obs]}, headers=admin)
        assert response.status_code == 200, response.text

    def labels(path: str, expected: int = 1) -> list[str]:
        # Each space's tracker takes its frame on its own time: wait for as many targets as
        # the read should show (a read made between the two trackers' frames showed one).
        deadline = time.monotonic() + 5
        while True:
            body = client.get(path, headers=admin).json()
            rows = body.get("items", body.get("tracks"))
            if len(rows) >= expected or time.monotonic() > deadline:
                return sorted(r["label"] for r in rows)
            time.sleep(0.1)

    assert labels("/api/v1/targets?state=all", expected=2) == ["a", "b"]
    assert labels(f"/api/v1/targets?state=all&space_id={spaces[0]}") == ["a"]
    assert labels(f"/api/v1/targets?state=all&space_id={spaces[1]}") == ["b"]
    since = now - 1
    assert labels(f"/api/v1/targets/tracks?state=all&since={since}&space_id={spaces[1]}") == ["b"]
    assert client.get("/api/v1/targets?space_id=0", headers=admin).status_code == 422

    # A labelled target stays live for a minute after its last detection: each space's stream
    # names its own target and no other.
    bearer = {"Authorization": "Bearer test-admin-token"}
    for space, label in zip(spaces, ("a", "b"), strict=True):
        with client.websocket_connect(f"/api/v1/ws/targets?space_id={space}", headers=bearer) as ws:
            deadline = time.monotonic() + 5
            while True:
                message = ws.receive_json()
                if message["targets"] or time.monotonic() > deadline:
                    break
        assert [t["label"] for t in message["targets"]] == [label]
    with pytest.raises(WebSocketDisconnect) as info:
        with client.websocket_connect("/api/v1/ws/targets?space_id=x", headers=bearer) as ws:
            ws.receive_json()
    assert info.value.code == 1008
