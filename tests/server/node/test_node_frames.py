"""A real camera's image reaches the service from its node: a node on an unplaced camera
detects nothing but uploads its newest frame at most once a second, served by
GET /cameras/{id}/frame.jpg, so the camera can be placed from floor points. The node runs
in-process against the real app (its HTTP client on the app's test transport)."""

from __future__ import annotations

import threading
import time

import cv2
import numpy as np
import pytest

from server.node.config import CameraConfig, NodeConfig
from server.node.frames import Frame
from server.node.runner import Node
from tests.support.waiting import wait_until


# The node's side is the same on both databases (the service's side runs on both in
# test_api_placement.py).
@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_node_uploads_an_unplaced_cameras_frames_at_most_once_a_second(client, admin, tmp_path):
    cid = client.post(
        "/api/v1/cameras", json={"name": "porch", "width": 320, "height": 240}, headers=admin
    ).json()["id"]
    token = client.post(
        "/api/v1/tokens",
        json={"name": "porch node", "scopes": ["ingest"], "camera_ids": [cid]},
        headers=admin,
    ).json()["token"]
    # A real file the node opens at start; the test hands its reader's queue its own frames.
    clip = str(tmp_path / "porch.avi")
    writer = cv2.VideoWriter(clip, cv2.VideoWriter_fourcc(*"MJPG"), 5.0, (320, 240))
    for _ in range(3):
        writer.write(np.zeros((240, 320, 3), np.uint8))
    writer.release()
    config = NodeConfig(cameras=[CameraConfig(name="porch", source=clip)])
    node = Node(config, "http://testserver/api/v1", token)
    node.client._http = client  # the app's own transport
    client.headers["Authorization"] = f"Bearer {token}"
    try:
        node.prepare()
        run = node.cameras[0]
        assert run.network is None  # unplaced: frames only
        loop = threading.Thread(target=node._detect_loop, args=(run,), daemon=True)
        loop.start()
        sent, served = [], []
        started = time.monotonic()
        for k in range(1, 5):
            image = np.full((240, 320, 3), 40 * k, np.uint8)
            run.source.frames.put(Frame(seq=k, received=time.time(), image=image))
            # The detector takes it and keeps it for the upload.
            wait_until(
                lambda image=image: node.frames._newest.get(cid, (None,))[0] is image,
                what=f"frame {k} taken by the detector",
                stalled_after_s=5,
                poll_s=0.01,
            )
            # Time must pass between the heartbeats: the uploads' pace is the scenario.
            time.sleep(max(0.0, started + 0.65 * k - time.monotonic()))
            node._heartbeat()  # the heartbeat thread's work: health, and the frame when due
            got = client.get(f"/api/v1/cameras/{cid}/frame.jpg", headers=admin)
            assert got.status_code == 200, got.text
            served.append(float(got.headers["X-Frame-Received"]))
            shown = cv2.imdecode(np.frombuffer(got.content, np.uint8), cv2.IMREAD_GRAYSCALE)
            sent.append(round(float(shown.mean()) / 40))
        # Heartbeats ~0.65 s apart: frames 1 and 3 are sent (1.1 s between uploads), 2 and 4
        # come too soon after them and wait; the image served is the last one uploaded.
        assert sent == [1, 1, 3, 3], sent
        assert len(set(served)) == 2 and np.diff(sorted(set(served)))[0] >= 1.0
        assert node.frames.uploaded == 2
        assert run.detected == 0
    finally:
        node.stop_event.set()
        del client.headers["Authorization"]
