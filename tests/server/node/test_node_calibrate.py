"""`intspace node calibrate`: the coverage of ROS camera_calibration, and the whole command
against a real service.

The service's twin cannot hold a chessboard up to one of its cameras (its loop renders the
home, the robot and the walkers only), so the end-to-end test renders the board views
in-process with core.sim's renderer (the twin's own camera `cam_living_sw`, its lens and sensor
noise, the home behind the board) and serves them as an MJPEG stream with X-Timestamp headers
from a small local server, as an IP camera or the twin's stream.mjpg would. The command reads
that stream, keeps the views, submits them to `intspace serve` as a photo calibration run, waits
for it and applies it; the applied intrinsics are scored against the rendering camera's true K
(ground truth used for scoring only).
"""

from __future__ import annotations

import math
import subprocess
import sys

import cv2
import httpx
import numpy as np
import pytest

from server.node.calibrate import (
    MIN_PARAM_DISTANCE,
    BoardCapture,
    Coverage,
    board_view_params,
)
from tests.support.mjpeg_stream import MjpegStream
from tests.support.service import WITHOUT_TWIN, clean_env, start_service

TOKEN = "node-calibrate-admin-token"
HEADERS = {"Authorization": f"Bearer {TOKEN}"}
CAMERA = "cam_living_sw"
PATTERN = (9, 6)
SQUARE = 0.04


def _grid(cols: int, rows: int, origin, step, shear: float = 0.0) -> np.ndarray:
    r, c = np.divmod(np.arange(cols * rows), cols)
    return np.column_stack([origin[0] + c * step + shear * r * step, origin[1] + r * step])


# -- coverage ------------------------------------------------------------------------------------


def test_view_parameters_follow_ros_camera_calibration():
    # A square-on 9x6 board of 20 px spacing centred in a 640x480 image: outline 160 x 100 px.
    corners = _grid(9, 6, (240.0, 190.0), 20.0)
    x, y, size, skew = board_view_params(corners, PATTERN, (640, 480))
    border = math.sqrt(160 * 100)
    assert size == pytest.approx(math.sqrt(160 * 100 / (640 * 480)))
    assert skew == pytest.approx(0.0, abs=1e-12)
    assert x == pytest.approx((320 - border / 2) / (640 - border))
    assert y == pytest.approx((240 - border / 2) / (480 - border))
    # Sheared by 0.25 per row: the corner angle at the top right is atan2(1, 0.25) from the
    # rows, so skew = 2 |pi/2 - (pi - atan2(1, 0.25))| (ROS's _calculate_skew).
    sheared = board_view_params(_grid(9, 6, (200.0, 190.0), 20.0, 0.25), PATTERN, (640, 480))
    angle = math.pi - math.atan2(1.0, 0.25)
    assert sheared[3] == pytest.approx(2 * abs(math.pi / 2 - angle))
    with pytest.raises(ValueError, match="corners"):
        board_view_params(corners[:-1], PATTERN, (640, 480))


def test_coverage_keeps_new_views_and_fills_its_bars():
    coverage = Coverage((640, 480))
    first = np.array([0.2, 0.2, 0.2, 0.1])
    assert coverage.is_new(first)
    coverage.add(first, _grid(9, 6, (10.0, 10.0), 10.0))
    # Within ROS's L1 distance of 0.2: the same view again; beyond it: new.
    assert not coverage.is_new(first + np.array([0.05, 0.05, 0.05, 0.04]))
    assert coverage.is_new(first + np.array([0.1, 0.1, 0.0, MIN_PARAM_DISTANCE]))
    coverage.add(np.array([0.9, 0.9, 0.45, 0.6]), _grid(9, 6, (560.0, 400.0), 8.0))
    # x, y span 0.7 of 0.7; size and skew count from 0: 0.45 / 0.4 and 0.6 / 0.5, capped.
    assert coverage.progress == pytest.approx([1.0, 1.0, 1.0, 1.0])
    assert coverage.complete
    text = coverage.render()
    assert "X     [####################] 100%" in text
    assert coverage.cells[0, 0] and coverage.cells[-1, -1] and coverage.cells.sum() == 2


# -- end to end ----------------------------------------------------------------------------------


def _board_views(n: int, seed: int) -> tuple[np.ndarray, list[bytes]]:
    """Return the true K of CAMERA and `n` JPEG frames of a 9x6 board (4 cm squares) held in
    front of it: centres on a 4 x 3 grid of the image, 0.45 or 0.7 m away, tilted 15 or 35
    degrees about a random axis and turned up to 15 degrees."""
    from core.geometry.camera import undistort_points
    from core.geometry.rotations import rotvec_to_matrix
    from core.sim import default_scene
    from core.sim.motion import world_state
    from core.sim.render import renderer_for
    from core.sim.scene import Board

    board = Board(inner_corners=PATTERN, square_size=SQUARE, margin=1.0)
    scene = default_scene()
    renderer = renderer_for(scene)
    cam = renderer.camera(CAMERA)
    people = world_state(scene, 0.0).people
    rng = np.random.default_rng(seed)
    half = np.array([(PATTERN[0] - 1) * SQUARE / 2, (PATTERN[1] - 1) * SQUARE / 2, 0.0])
    frames = []
    for i in range(n):
        cell = 0.15 + 0.7 * (np.array([i % 4, (i // 4) % 3]) + 0.5) / np.array([4, 3])
        ray = undistort_points(cell * np.array([cam.width - 1, cam.height - 1]), cam.K, cam.dist)
        angle, phi = math.radians(15 + 20 * (i % 2)), rng.uniform(0, 2 * math.pi)
        R = rotvec_to_matrix(
            np.array(
                [angle * math.cos(phi), angle * math.sin(phi), math.radians(rng.uniform(-15, 15))]
            )
        )
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = (0.45 if i % 3 else 0.7) * np.array([ray[0], ray[1], 1.0]) - R @ half
        frame = renderer.render_board(CAMERA, board, cam.T_world_camera @ T, rng=rng, people=people)
        ok, jpeg = cv2.imencode(".jpg", frame.image, [cv2.IMWRITE_JPEG_QUALITY, 90])
        assert ok
        frames.append(jpeg.tobytes())
    return np.asarray(cam.K), frames


def test_calibrate_captures_views_from_a_stream_submits_and_applies_the_run(repo_root, tmp_path):
    K_true, frames = _board_views(14, seed=5)
    stream = MjpegStream(frames)
    service = start_service(tmp_path, token=TOKEN, env=WITHOUT_TWIN)
    api = service.api
    try:
        http_client = httpx.Client(base_url=api, headers=HEADERS, timeout=10)
        created = http_client.post("/cameras", json={"name": CAMERA, "width": 640, "height": 480})
        assert created.status_code == 201, created.text
        camera_id = created.json()["id"]
        env = clean_env()
        env["INTSPACE_TOKEN"] = TOKEN
        args = ["--camera", CAMERA, "--board", "9x6", "--square", str(SQUARE), "--api", api]
        done = subprocess.run(
            [
                sys.executable,
                "-m",
                "server.cli",
                "node",
                "calibrate",
                *args,
                "--source",
                stream.url,
                "--views",
                "10",
                "--timeout",
                "90",
                "--apply",
            ],
            cwd=repo_root,
            env=env,
            capture_output=True,
            text=True,
            timeout=240,
        )
        assert done.returncode == 0, done.stdout + done.stderr
        out = done.stdout
        print(out)
        # The coverage is shown as it fills, a view at a time, up to the ten asked for.
        assert "View 1/10 kept" in out and "View 10/10 kept" in out
        assert out.count("  Skew  [") == 10 and "cells" in out
        assert "Applied run" in out and TOKEN not in out + done.stderr

        camera = http_client.get(f"/cameras/{camera_id}").json()
        run = http_client.get(f"/calibration-runs/{camera['calibration_run_id']}").json()
        assert run["status"] == "succeeded" and run["source"] == "images"
        result = run["result"]
        assert len(result["per_view_rms"]) == 10 and camera["K"] == result["K"]
        K = np.asarray(camera["K"])
        std = result["std_intrinsics"]
        errors = {
            "fx": K[0, 0] - K_true[0, 0],
            "fy": K[1, 1] - K_true[1, 1],
            "cx": K[0, 2] - K_true[0, 2],
            "cy": K[1, 2] - K_true[1, 2],
        }
        print("errors against the true K (px):", errors, "standard deviations:", std)
        # The truth lies within 5 of the run's own standard deviations (~0.23 px here) of
        # each estimate: the views are unbiased (the rendered lens is k1 k2 p1 p2 with a
        # k3 of -0.002, which the fitted model omits; measured errors ~0.1-0.2 px).
        for name, error in errors.items():
            assert abs(error) < 5 * std[name], (name, error, std)
        assert result["rms"] < 0.3  # corners on rendered, noisy JPEG frames: ~0.1 px
        http_client.close()
    finally:
        service.stop()
        stream.close()


def _printed_board(x0: int, y0: int, square: int) -> np.ndarray:
    """Return a 640x480 grey image of a 10 x 7 squares (9x6 inner corners) board at (x0, y0)."""
    image = np.full((480, 640), 255, np.uint8)
    for r in range(7):
        for c in range(10):
            if (r + c) % 2 == 0:
                y, x = y0 + r * square, x0 + c * square
                image[y : y + square, x : x + square] = 0
    return cv2.GaussianBlur(image, (3, 3), 0.8)


def test_capture_keeps_a_view_once_and_ends_when_enough_are_kept():
    capture = BoardCapture(PATTERN, (640, 480), max_views=2, min_views=2)
    assert capture.offer(np.full((480, 640), 255, np.uint8)) is None  # no board
    first = capture.offer(_printed_board(40, 40, 24))
    assert first is not None and first.filename == "view-001.png"
    # The board's first inner corner is where its first four squares meet: (64, 64).
    assert np.allclose(first.corners[0], [63.5, 63.5], atol=0.3)
    decoded = cv2.imdecode(np.frombuffer(first.data, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert decoded.shape == (480, 640)  # lossless PNG of the frame, as it was seen
    assert capture.offer(_printed_board(42, 41, 24)) is None  # the same place: not new
    assert not capture.done and capture.seen == 2
    assert capture.offer(_printed_board(330, 250, 28), jpeg=b"jpeg bytes") is not None
    assert capture.views[1].data == b"jpeg bytes" and capture.done
