"""A camera node's throughput: frames per second decoded and detected per 640x480 camera on one
core, against spec 08's 30 frames per second.

Run from the repository root: python -m bench.bench_node
Frames: 150 frames of the twin's living-room camera (640 x 480, its default home: the robot
patrolling, a person walking), rendered at 10 Hz of simulated time and JPEG-encoded at the
quality the service streams (85), as a node receives them. Timed per frame (time.perf_counter,
one core: OpenCV and BLAS pools pinned to one thread): what the node's detector thread does,
JPEG decode, the masks (one polygon), core.localization.detections.detect_frame (robot marker
and people with the camera's calibration, background learnt first from 30 frames) and the
conversion to POST /observations rows. Prints the median and 95th percentile per frame and the
frames per second, and the decode and detect shares.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import time  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from core.localization import NetworkCamera  # noqa: E402
from core.localization.detect import MarkerDetectorConfig, PersonDetector  # noqa: E402
from core.localization.detections import detect_frame  # noqa: E402
from core.sim import UnicycleBase, default_scene, world_state  # noqa: E402
from core.sim.motion import Patrol  # noqa: E402
from core.sim.render import camera_model, renderer_for  # noqa: E402
from server.node.masks import apply_mask, polygon_mask  # noqa: E402
from server.node.runner import observation  # noqa: E402

CAMERA = "cam_living_sw"
N_FRAMES = 150
N_BACKGROUND = 30
RATE = 10.0
TARGET_FPS = 30.0
SEED = 0


def frames() -> tuple[list[bytes], NetworkCamera, float]:
    """Return the JPEG frames, the camera's nominal calibration (what the registry holds for
    a twin camera) and the robot marker's height."""
    scene = default_scene()
    renderer = renderer_for(scene)
    spec = next(c for c in scene.cameras if c.name == CAMERA)
    model = camera_model(spec)
    network = NetworkCamera.from_pose(
        model.K, model.dist, model.T_world_camera, (model.width, model.height), CAMERA
    )
    robot = scene.robot
    assert robot is not None and robot.marker is not None and robot.patrol is not None
    base = UnicycleBase.from_robot(robot, dt=0.05, rng=SEED)
    patrol = Patrol(robot.patrol, robot.limits)
    rng = np.random.default_rng(SEED)
    out = []
    for _ in range(N_FRAMES):
        for _ in range(round(1.0 / RATE / 0.05)):
            base.step(*patrol.command(base.state.pose))
        state = world_state(scene, base.state.time, base.state.pose)
        image = renderer.render(CAMERA, state, rng=rng).image
        ok, jpg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 85])
        assert ok
        out.append(jpg.tobytes())
    return out, network, robot.marker.height


def main() -> None:
    cv2.setNumThreads(1)
    jpegs, network, marker_height = frames()
    marker = MarkerDetectorConfig()
    people = PersonDetector()
    mask = polygon_mask((640, 480), [[[0, 0], [60, 0], [60, 40], [0, 40]]])
    for jpg in jpegs[:N_BACKGROUND]:
        people.learn(apply_mask(cv2.imdecode(np.frombuffer(jpg, np.uint8), cv2.IMREAD_COLOR), mask))
    decode, total, found = [], [], 0
    for jpg in jpegs:
        t0 = time.perf_counter()
        image = cv2.imdecode(np.frombuffer(jpg, np.uint8), cv2.IMREAD_COLOR)
        t1 = time.perf_counter()
        image = apply_mask(image, mask)
        dets = detect_frame(
            image, marker=marker, marker_height=marker_height, people=people, camera=network
        )
        rows = [observation(1, 0.0, d) for d in dets]
        t2 = time.perf_counter()
        decode.append(t1 - t0)
        total.append(t2 - t0)
        found += sum(r is not None for r in rows)
    ms = 1000 * np.array(total)
    fps = 1.0 / np.mean(total)
    print(f"camera node, one core, {CAMERA} 640x480, {N_FRAMES} JPEG frames (q85), seed {SEED}")
    print(f"  per frame: median {np.median(ms):.2f} ms, p95 {np.percentile(ms, 95):.2f} ms")
    dec = 1000 * np.mean(decode)
    print(f"  decode {dec:.2f} ms, mask + detect {np.mean(ms) - dec:.2f} ms")
    print(f"  detections {found} ({found / N_FRAMES:.2f} per frame)")
    print(
        f"  frames/s per camera {fps:8.1f}   (spec 08: >= {TARGET_FPS:g}; {fps / TARGET_FPS:.1f}x)"
    )


if __name__ == "__main__":
    main()
