"""GET /cameras/{id}/stream.mjpg: the twin's cameras as MJPEG streams, each part stamped."""

from __future__ import annotations

import threading
import time

import cv2
import numpy as np

from server.node.mjpeg import MjpegParser, boundary_of
from server.services.twin import TwinFrame
from tests.support.waiting import wait_until_unchanged


class _FakeTwin:
    """A twin with one camera whose frame changes every `period` seconds (a gradient whose
    level is the frame's index, so that a decoded part names the frame it came from)."""

    def __init__(self, camera_id: int, period: float = 0.05) -> None:
        self.camera_ids = {"cam": camera_id}
        self._id = camera_id
        self._period = period
        self._start = time.time()
        self.reads = 0
        self._lock = threading.Lock()

    def frame(self, camera_id: int) -> TwinFrame | None:
        with self._lock:
            self.reads += 1
        if camera_id != self._id:
            return None
        k = int((time.time() - self._start) / self._period)
        image = np.full((48, 64, 3), (10 * k) % 250, dtype=np.uint8)
        return TwinFrame(camera_id, "cam", self._start + k * self._period, image)


def test_stream_parts_carry_the_frames_and_their_capture_times(client, admin):
    twin = _FakeTwin(camera_id=3)
    client.app.state.runtime.twin = twin
    parts = []
    with client.stream("GET", "/api/v1/cameras/3/stream.mjpg", headers=admin) as response:
        assert response.status_code == 200
        parser = MjpegParser(boundary_of(response.headers["content-type"]))
        for chunk in response.iter_bytes():
            parts.extend(parser.feed(chunk))
            if len(parts) >= 4:
                break
    stamps = [p.timestamp for p in parts]
    # Each part is a new frame: strictly increasing stamps, on the fake twin's 50 ms grid
    # (the header prints microseconds: 1e-6 s / 0.05 s = 2e-5 of a step).
    assert np.all(np.diff(stamps) > 0)
    steps = np.diff(stamps) / 0.05
    np.testing.assert_allclose(steps, np.round(steps), atol=5e-5)
    for p in parts:
        image = cv2.imdecode(np.frombuffer(p.body, np.uint8), cv2.IMREAD_COLOR)
        assert image.shape == (48, 64, 3)
        k = round((p.timestamp - twin._start) / 0.05)
        # JPEG of a flat image: within 2 grey levels of the level the frame was drawn with.
        assert abs(float(image.mean()) - (10 * k) % 250) < 2.0


def test_stream_needs_a_token_in_the_header_and_a_twin_camera(client, admin):
    client.app.state.runtime.twin = _FakeTwin(camera_id=3)
    assert client.get("/api/v1/cameras/3/stream.mjpg").status_code == 401
    # A token in the URL is not a credential.
    token = admin["Authorization"].split()[1]
    assert client.get(f"/api/v1/cameras/3/stream.mjpg?token={token}").status_code == 401
    missing = client.get("/api/v1/cameras/4/stream.mjpg", headers=admin)
    assert missing.status_code == 404
    assert "not a camera of the twin" in missing.json()["detail"]


def test_stream_is_404_without_the_twin(client, admin):
    response = client.get("/api/v1/cameras/1/stream.mjpg", headers=admin)
    assert response.status_code == 404
    assert "INTSPACE_SIMULATION=true" in response.json()["detail"]


def test_stream_generator_stops_when_the_client_leaves(client, admin):
    twin = _FakeTwin(camera_id=3, period=0.02)
    client.app.state.runtime.twin = twin
    with client.stream("GET", "/api/v1/cameras/3/stream.mjpg", headers=admin) as response:
        for _ in response.iter_bytes():
            break
    # The generator notices and stops reading the twin (no read in 0.1 s: five frame periods).
    before = wait_until_unchanged(
        lambda: twin.reads, what="the twin's reads", interval_s=0.1, stalled_after_s=5
    )
    time.sleep(0.5)  # time must pass: nothing reads the twin in it
    # A generator still running would read the twin every 10 ms (about 50 reads here).
    assert twin.reads - before <= 1
