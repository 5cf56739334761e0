"""`intspace node --source rtsp://...` against a local RTSP camera (GStreamer's RTSP server
serving the twin's living-room view as H.264, tests/support/rtsp_server.py), as against an IP
camera: frames are read, the robot's marker is detected and tracked where it stands, and a
camera that goes away for 10 s is read again within 5 s of its return (spec 08).

The server runs under the system Python with PyGObject (Debian: python3-gi,
gir1.2-gst-rtsp-server-1.0, gstreamer1.0-plugins-good, gstreamer1.0-plugins-ugly). Without
them the test is skipped with the reason, except under CI=true, where it fails.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import time
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest

from core.sim import WorldState, default_scene
from core.sim.motion import Pose2D
from core.sim.render import renderer_for
from tests.support.camera_node import installed_camera, start_node
from tests.support.ports import free_port
from tests.support.service import WITHOUT_TWIN, start_service
from tests.support.waiting import wait_until

TOKEN = "rtsp-test-admin-token"
HEADERS = {"Authorization": f"Bearer {TOKEN}"}
SYSTEM_PYTHON = Path("/usr/bin/python3")
SERVER = Path(__file__).resolve().parents[2] / "support" / "rtsp_server.py"
PACKAGES = (
    "python3-gi gir1.2-gst-rtsp-server-1.0 gstreamer1.0-plugins-good gstreamer1.0-plugins-ugly"
)
CAMERA = "cam_living_sw"
# Where the robot stands in the clip: in the middle of the living room, in CAMERA's view.
ROBOT = Pose2D(2.0, 2.0, 0.3)


def _rtsp_unavailable() -> str | None:
    """Return why the local RTSP server cannot run here, None when it can."""
    if not SYSTEM_PYTHON.exists():
        return f"no system Python at {SYSTEM_PYTHON}"
    check = subprocess.run(
        [str(SYSTEM_PYTHON), str(SERVER), "--check"], capture_output=True, text=True, timeout=60
    )
    return None if check.returncode == 0 else (check.stderr.strip() or "the check failed")


@pytest.fixture(scope="module")
def rtsp_ready() -> None:
    reason = _rtsp_unavailable()
    if reason is None:
        return
    message = f"GStreamer's RTSP server is not usable ({reason}); apt-get install {PACKAGES}"
    if os.environ.get("CI", "").lower() == "true":
        pytest.fail(message)
    pytest.skip(message)


def _clip(path: Path, frames: int = 30, fps: float = 10.0, repeats: int = 20) -> None:
    """Write the twin's view of CAMERA with the robot at ROBOT and nobody else in the home:
    `frames` renders, written `repeats` times over (60 s at the defaults: the stream lasts the
    whole test, and the only outage the node sees is the one the test makes)."""
    scene = default_scene()
    renderer = renderer_for(scene)
    away = tuple((1e4, 1e4) for _ in scene.people)
    images = [
        renderer.render(CAMERA, WorldState(k / fps, ROBOT, away), rng=k).image
        for k in range(frames)
    ]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (640, 480))
    for _ in range(repeats):
        for image in images:
            writer.write(image)
    writer.release()


class _RtspCamera:
    """The RTSP server subprocess, (re)started on a fixed port."""

    def __init__(self, clip: Path) -> None:
        self.clip = clip
        self.port = free_port()
        self.url = f"rtsp://127.0.0.1:{self.port}/cam"
        self.process: subprocess.Popen | None = None

    def start(self) -> None:
        self.process = subprocess.Popen(
            [str(SYSTEM_PYTHON), str(SERVER), "--port", str(self.port), str(self.clip)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        assert self.process.stdout is not None
        line = self.process.stdout.readline()
        if not line.startswith("ready"):
            self.process.kill()
            raise AssertionError(f"the RTSP server did not start: {self.process.stderr.read()}")

    def stop(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()


def test_node_reads_an_rtsp_camera_tracks_its_robot_and_reconnects(rtsp_ready, repo_root, tmp_path):
    clip = tmp_path / "clip.avi"
    _clip(clip)
    camera = _RtspCamera(clip)
    camera.start()
    service = start_service(tmp_path / "service", token=TOKEN, env=WITHOUT_TWIN)
    api = service.api
    node = None
    node_log = tmp_path / "node.log"
    http = httpx.Client(base_url=api, headers=HEADERS, timeout=10)
    try:
        space = http.post("/spaces", json={"name": "flat"}).json()["id"]
        # The robot the camera sees is registered: a space without one makes no robot target.
        http.post("/robots", json={"name": "robot", "space_id": space}).raise_for_status()
        # The camera as its installation calibrated it (not the twin's true camera).
        body = installed_camera(default_scene(), CAMERA, space_id=space)
        created = http.post("/cameras", json=body)
        assert created.status_code == 201, created.text
        camera_id = created.json()["id"]
        node = start_node(
            repo_root,
            *("--source", camera.url),
            *("--camera", CAMERA, "--space", str(space), "--api", api),
            *("--summary", "2"),
            # The twin's people are coloured cylinders, no people to the neural detector.
            *("--detector", "background"),
            token=TOKEN,
            log=node_log,
        )

        def health() -> dict:
            return http.get(f"/cameras/{camera_id}").json()["health"]

        def robot() -> dict | None:
            items = http.get("/targets", params={"kind": "robot"}).json()["items"]
            return items[0] if items else None

        try:
            target = wait_until(
                robot, what="a robot target from the RTSP camera's frames", stalled_after_s=40
            )
        except AssertionError as exc:
            raise AssertionError(f"{exc}\nnode:\n{node_log.read_text()}") from None
        wait_until(
            lambda: (health()["fps"] or 0) > 0,
            what="a heartbeat counting the camera's frames",
            stalled_after_s=5,
        )
        error = float(np.hypot(target["xy"][0] - ROBOT.x, target["xy"][1] - ROBOT.y))
        print(f"robot at {target['xy']}, {100 * error:.2f} cm from where it stands")
        # 5 cm: spec 08's RMSE for points at a known height (the marker's). One camera with its
        # installed calibration locates the marker to about a centimetre; H.264 at the
        # encoder's default quality moves the marker's centroid by well under a pixel.
        assert error < 0.05, (target, node_log.read_text())

        # The camera goes away for 10 s (an IP camera rebooting), then returns on its address.
        camera.stop()
        time.sleep(10.0)  # the outage itself: time must pass with the camera away
        # ... and the node noticed it: its heartbeat counts the stall.
        wait_until(lambda: health()["stalls"] >= 1, what="a heartbeat saying so", stalled_after_s=5)
        camera.start()
        back = time.time()

        def received(h: dict) -> float:
            # The node stamps an RTSP frame with its own clock plus the offset it measured to
            # the service's; this machine's clock is the node's.
            return h["last_frame_t"] - h["clock_offset_s"]

        seen = wait_until(
            lambda: (h := health())["last_frame_t"] is not None and received(h) > back and h,
            what="frames after the camera returned",
            stalled_after_s=8,
        )
        delay = received(seen) - back
        print(f"read again {delay:.2f} s after the camera returned; health {seen}")
        # Spec 08: within 5 s of its return (the back-off is capped at 2 s in an outage's first
        # minute, and FFmpeg's open probes the stream for about 2 s more).
        assert delay <= 5.0, (delay, node_log.read_text())
        assert seen["reconnects"] >= 1 and seen["stalls"] >= 1

        # ... and keeps posting: the robot's track takes frames captured after the return.
        wait_until(
            lambda: (r := robot()) is not None and r["t"] > back,
            what="the robot tracked from frames after the camera returned",
            stalled_after_s=8,
        )
        # Its output said each change once: connected, lost, reconnecting, back; summaries
        # every 2 s; never FFmpeg's or OpenCV's own messages, however many attempts failed.
        wait_until(
            lambda: "summary so far" in node_log.read_text().split("back after")[-1],
            what="a summary after the return",
            stalled_after_s=5,
        )
        node.send_signal(signal.SIGINT)
        assert node.wait(15) == 0
        lines = node_log.read_text().splitlines()
        said = [line for line in lines if "summary" not in line]

        def count(words: str) -> int:
            return sum(words in line for line in said)

        assert count(f"camera {CAMERA}: connected to {camera.url}") == 1, lines
        assert count(f"camera {CAMERA}: stalled") + count("connection lost") == 1, lines
        assert count(f"camera {CAMERA}: reconnecting") == 1, lines
        assert count(f"camera {CAMERA}: back after") == 1, lines
        # The outage (10 s) plus the read timeout (2 s): at most a line per distinct reason
        # for the failed attempts (refused, then perhaps no video while the server starts).
        assert count("still unreachable") <= 2, lines
        assert not [line for line in lines if not line.startswith("intspace node: ")], lines
        (final,) = [line for line in lines if "summary at the end: camera" in line]
        counts = re.search(r"(\d+) detection\(s\); (\d+) stall\(s\), (\d+) reconnect\(s\)", final)
        assert counts is not None, final
        detections, stalls, reconnects = (int(c) for c in counts.groups())
        assert detections > 0 and stalls >= 1 and reconnects >= 1, final
    finally:
        http.close()
        if node is not None and node.poll() is None:
            node.send_signal(signal.SIGINT)
            try:
                node.wait(15)
            except subprocess.TimeoutExpired:
                node.kill()
        camera.stop()
        service.stop()
