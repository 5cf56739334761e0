"""`intspace node --record DIR` and a recording replayed as a source (`--source DIR`).

End to end against a real `intspace serve`: the frames of the twin's camera `cam_living_sw`
watching the robot drive are rendered in-process with core.sim's renderer and served as an MJPEG
stream with X-Timestamp headers by a small local server (the service's twin renders only while
it runs its own loop, which takes a minute to start); the camera is registered with the home's
installed calibration, as the twin registers it. A node records the stream; a second node
replays the recording; both post to the service, whose stored detections are compared.
"""

from __future__ import annotations

import json
import sqlite3
import subprocess
import time
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest

from core.errors import InvalidInput
from server.node.frames import Frame
from server.node.record import (
    RECORDING_FILE,
    Recorder,
    RecordingSource,
    folder_name,
    is_recording,
    recorded_frames,
)
from tests.support.camera_node import installed_camera, start_node
from tests.support.mjpeg_stream import MjpegStream
from tests.support.service import WITHOUT_TWIN, start_service
from tests.support.waiting import wait_until

TOKEN = "node-record-admin-token"
HEADERS = {"Authorization": f"Bearer {TOKEN}"}
CAMERA = "cam_living_sw"


# -- the recording format ------------------------------------------------------------------------


def _record(root: Path, n: int, period: float, t0: float = 1000.0) -> list[bytes]:
    recorder = Recorder(root, [{"name": "cam/../a b", "camera_id": 7, "width": 32, "height": 24}])
    jpegs = []
    for k in range(n):
        ok, jpeg = cv2.imencode(".jpg", np.full((24, 32, 3), 10 * k, np.uint8))
        assert ok
        jpegs.append(jpeg.tobytes())
        obs = [{"camera_id": 7, "t": t0 + k * period, "pixel": [k, 2.0], "kind": "robot"}]
        recorder.write(
            "cam/../a b", Frame(k + 1, 0.0, t0 + k * period, jpeg=jpegs[-1]), obs[0]["t"], obs
        )
    recorder.close()
    return jpegs


def test_a_recording_keeps_frames_times_and_detections_under_a_safe_folder(tmp_path):
    root = tmp_path / "rec"
    jpegs = _record(root, 3, 0.1)
    assert is_recording(str(root)) and not is_recording(str(tmp_path))
    meta = json.loads((root / RECORDING_FILE).read_text())
    # The camera's name never becomes a path: only letters, digits, '.', '-' and '_'.
    assert meta["cameras"][0]["folder"] == folder_name(0, "cam/../a b") == "00-cam_.._a_b"
    frames = list(recorded_frames(root, "cam/../a b"))
    assert [f.t for f in frames] == [1000.0, 1000.1, 1000.2]
    assert [f.path.read_bytes() for f in frames] == jpegs  # the stream's bytes, unchanged
    assert frames[1].detections == [{"t": 1000.1, "pixel": [1, 2.0], "kind": "robot"}]
    with pytest.raises(InvalidInput, match="already holds a recording"):
        Recorder(root, [])
    with pytest.raises(InvalidInput, match=r"has no camera 'other' \(it has 'cam/../a b'\)"):
        list(recorded_frames(root, "other"))
    # A node killed while writing leaves a last line cut short: the recording ends before it.
    index = root / meta["cameras"][0]["folder"] / "index.jsonl"
    index.write_text(index.read_text() + '{"seq": 4, "t": 10', encoding="utf-8")
    assert len(list(recorded_frames(root, "cam/../a b"))) == 3
    # A folder name that leaves the recording is refused.
    meta["cameras"][0]["folder"] = "../elsewhere"
    (root / RECORDING_FILE).write_text(json.dumps(meta))
    with pytest.raises(InvalidInput, match="not valid"):
        list(recorded_frames(root, "cam/../a b"))


@pytest.mark.parametrize("realtime", [True, False])
def test_replay_keeps_the_recorded_spacing_shifted_to_now(tmp_path, realtime):
    root = tmp_path / "rec"
    jpegs = _record(root, 6, 0.1)
    source = RecordingSource("cam/../a b", root, realtime=realtime)
    started = time.time()
    source.start()
    taken: list[Frame] = []
    while (frame := source.frames.take(timeout=5)) is not None:
        taken.append(frame)
    source.join(5)
    # Every frame, byte for byte, even when replayed as fast as it is taken.
    assert [f.jpeg for f in taken] == jpegs and source.frames.dropped == 0
    times = np.array([f.t for f in taken])
    # One offset for the whole recording: the spacing is the recorded one to the microsecond.
    assert np.allclose(np.diff(times), 0.1, atol=1e-6)
    assert abs(times[0] - started) < 0.5  # the first frame is captured now
    received = np.array([f.received for f in taken])
    if realtime:
        # At its own pace: each frame published at its shifted time (thread wake-up: < 50 ms).
        assert np.all(np.abs(received - times) < 0.05), received - times
    else:
        assert received[-1] - received[0] < 0.4  # faster than the 0.5 s recorded


# -- end to end ----------------------------------------------------------------------------------


def _robot_frames(n: int) -> tuple[list[bytes], dict]:
    """Return `n` JPEG frames of CAMERA with the robot driving 4 cm a frame across its view,
    the walkers far away, and the camera's registry row (the home's installed calibration)."""
    from core.sim import default_scene
    from core.sim.motion import Pose2D, WorldState
    from core.sim.render import renderer_for

    scene = default_scene()
    renderer = renderer_for(scene)
    away = tuple((1e4, 1e4) for _ in scene.people)
    frames = []
    for k in range(n):
        pose = Pose2D(1.0 + 0.04 * k, 1.2 + 0.02 * k, 0.3)
        image = renderer.render(CAMERA, WorldState(0.1 * k, pose, away), rng=k).image
        ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 85])
        assert ok
        frames.append(jpeg.tobytes())
    return frames, installed_camera(scene, CAMERA)


def _node(repo_root: Path, *args: str) -> subprocess.Popen:
    return start_node(repo_root, *args, token=TOKEN)


def _stored(data_dir: Path) -> tuple[np.ndarray, list[str]]:
    """Return the service's stored detections (t, u, v, cxx, cxy, cyy, height) in the order
    they were posted, and their kinds."""
    with sqlite3.connect(f"file:{data_dir / 'intspace.sqlite3'}?mode=ro", uri=True) as db:
        rows = db.execute(
            "SELECT t, u, v, cxx, cxy, cyy, height, kind FROM detections ORDER BY id"
        ).fetchall()
    return np.array([r[:-1] for r in rows], dtype=np.float64).reshape(-1, 7), [r[-1] for r in rows]


def _recorded(recording: Path) -> tuple[np.ndarray, list[str]]:
    """Return the detections of the frames recorded in `recording` so far (t, u, v, cxx, cxy,
    cyy, height) in the order they were recorded, and their kinds."""
    recorded = list(recorded_frames(recording, CAMERA))
    kept = np.array(
        [
            [d["t"], *d["pixel"], d["cov"][0][0], d["cov"][0][1], d["cov"][1][1], d["height"]]
            for f in recorded
            for d in f.detections
        ]
    )
    return kept, [d["kind"] for f in recorded for d in f.detections]


def _distinct(rows: np.ndarray, kinds: list[str]) -> set[tuple]:
    """Return the distinct detections, times rounded to 10 us (a shift's rounding: < 1 us)."""
    return {(round(r[0], 5), *r[1:].tolist(), kind) for r, kind in zip(rows, kinds, strict=True)}


def test_a_recorded_stream_replayed_posts_the_same_detections(repo_root, tmp_path):
    frames, row = _robot_frames(30)
    stream = MjpegStream(frames)
    data_dir = tmp_path / "service"
    data_dir.mkdir()
    service = start_service(data_dir, token=TOKEN, env=WITHOUT_TWIN)
    api = service.api
    recording = tmp_path / "recording"
    try:
        created = httpx.post(f"{api}/cameras", json=row, headers=HEADERS, timeout=10)
        assert created.status_code == 201, created.text
        # The robot the frames show is registered (like the camera, in no space): without one,
        # its space makes no robot target.
        robot = httpx.post(f"{api}/robots", json={"name": "robot"}, headers=HEADERS, timeout=10)
        assert robot.status_code == 201, robot.text
        common = ["--camera", CAMERA, "--api", api, "--background-frames", "5"]
        # Read with the node's MJPEG reader (the stream's own JPEG bytes are recorded); a
        # stream read by OpenCV is recorded re-encoded, and replays only approximately. The
        # frames are the twin's renders, so the twin's people detector (the replay runs the
        # one the recording names).
        config = tmp_path / "node.yaml"
        config.write_text(
            f"cameras:\n  - {{name: {CAMERA}, source: '{stream.url}', reader: mjpeg, "
            "detector: background}\n",
            encoding="utf-8",
        )
        recorder = _node(
            repo_root,
            "--config",
            str(config),
            "--record",
            str(recording),
            *common[2:],
        )
        index = recording / folder_name(0, CAMERA) / "index.jsonl"

        def frames_recorded() -> int:
            assert recorder.poll() is None, recorder.communicate()[1]
            return index.read_text().count("\n") if index.is_file() else 0

        wait_until(
            lambda: frames_recorded() >= 25,
            what="25 frames recorded",
            stalled_after_s=60,
            progress=frames_recorded,
            poll_s=0.2,
        )
        # The detections of the frames recorded so far reach the service.
        sent = _distinct(*_recorded(recording))
        wait_until(
            lambda: sent <= _distinct(*_stored(data_dir)),
            what="the recorded frames' detections stored",
            stalled_after_s=10,
            progress=lambda: len(_stored(data_dir)[1]),
        )
        # Killed, not stopped: what a recording holds must not depend on a clean exit (its
        # index is flushed a frame at a time; a line cut short ends it).
        recorder.kill()
        recorder.communicate(timeout=30)
        kept, kept_kinds = _recorded(recording)
        posted, kinds = _stored(data_dir)
        assert kinds.count("robot") >= 20, kinds
        # Every detection the node posted while recording is in the recording, at its time
        # (the last frames' may have been recorded but not yet posted when it was killed).
        # The uploader retries a batch whose answer timed out, so the service may hold a
        # detection twice: compare distinct detections.
        recorded_set = _distinct(kept, kept_kinds)
        live = _distinct(posted, kinds)
        assert live <= recorded_set and len(recorded_set) - len(live) <= 4, (
            len(live),
            len(recorded_set),
        )

        replay = _node(repo_root, "--source", str(recording), "--fast", *common)
        _, err = replay.communicate(timeout=60)
        assert replay.returncode == 0, err
        assert "recording" in err and TOKEN not in err
        both, both_kinds = _stored(data_dir)
        assert np.array_equal(both[: len(posted)], posted)
        new = both[len(posted) :]
        # The same detections (pixels, covariances, heights, kinds) of the same frames, at
        # the recorded times shifted by one offset: the JPEG bytes and the detectors are the
        # same.
        shift = new[:, 0].min() - kept[:, 0].min()
        assert shift > 0
        shifted = new.copy()
        shifted[:, 0] -= shift
        replayed = _distinct(shifted, both_kinds[len(posted) :])
        assert replayed == recorded_set, (
            sorted(replayed - recorded_set),
            sorted(recorded_set - replayed),
        )
    finally:
        service.stop()
        stream.close()
