"""What the ceiling cameras report to the tracker, frame by frame, in the twin.

* Unsynchronised cameras' points (`async_camera_frames`, spec 08's conditions `ASYNC_*`): each
  camera at its own rate and phase, each walker's point projected into the cameras that see it,
  with pixel noise, missed detections and clutter.
* Rendered images through the detectors (`rendered_frames`): every calibrated camera renders
  the home with the robot patrolling and the walkers at `RENDER_RATE_HZ` with its own phase,
  and core.localization.detections.detect_frame finds the robot's marker and the people in
  each image, against a background learnt from the empty home.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from core.localization import NetworkCamera
from core.localization.detect import MarkerDetectorConfig, PersonDetector
from core.localization.detections import FrameDetection, detect_frame
from core.sim.crowd import crowd_around, robot_poses, walkers_at
from core.sim.motion import Pose2D, WorldState, simulate_patrol
from core.sim.network_cameras import CalibratedCameras
from core.sim.render import ExposureChanges, Renderer, renderer_for
from core.sim.scene import Robot, Scene

Array = NDArray[np.float64]

# Spec 08's conditions.
ASYNC_RATE_HZ = 10.0
ASYNC_NOISE_PX = 0.7
ASYNC_MISS = 0.05
# False detections per camera frame (Poisson mean), uniform over the image.
ASYNC_CLUTTER = 0.3
ASYNC_HEIGHT_M = 1.0


@dataclass(frozen=True)
class CameraFrameDetections:
    """One camera frame: its capture time (s), the camera's index, the detections' pixels
    (D, 2), and which body each came from (-1 for clutter; for scoring only)."""

    t: float
    camera: int
    pixels: Array
    source: NDArray[np.int64]


def async_camera_frames(
    scene: Scene,
    cameras: list[NetworkCamera],
    duration_s: float,
    rng: np.random.Generator,
    *,
    rate_hz: float = ASYNC_RATE_HZ,
    noise_px: float = ASYNC_NOISE_PX,
    miss: float = ASYNC_MISS,
    clutter: float = ASYNC_CLUTTER,
    height: float = ASYNC_HEIGHT_M,
) -> list[CameraFrameDetections]:
    """Return every camera's frames over `duration_s`, in capture-time order: each camera at
    `rate_hz` with its own random phase and a small jitter, each walker's point at `height`
    projected into the cameras that see it (in front, inside the image), Gaussian pixel noise,
    a detection missed with probability `miss`, and Poisson(`clutter`) false detections."""
    period = 1.0 / rate_hz
    frames: list[CameraFrameDetections] = []
    for k, cam in enumerate(cameras):
        phase = rng.uniform(0.0, period)
        n = int(np.floor((duration_s - phase) / period)) + 1
        times = phase + period * np.arange(n) + rng.normal(0.0, 0.002, n)
        times = np.clip(times, 0.0, duration_s)
        P = walkers_at(scene, times)  # (n, B, 2)
        B = P.shape[1]
        pts = np.concatenate([P, np.full((n, B, 1), height)], axis=2).reshape(-1, 3)
        seen = cam.in_view(pts).reshape(n, B)
        uv = cam.project(pts).reshape(n, B, 2)
        uv = uv + rng.normal(0.0, noise_px, uv.shape)
        seen &= rng.random((n, B)) >= miss
        w, h = cam.image_size if cam.image_size is not None else (640, 480)
        n_clutter = rng.poisson(clutter, n)
        for i in range(n):
            src = np.flatnonzero(seen[i])
            fake = np.column_stack(
                [rng.uniform(0, w, n_clutter[i]), rng.uniform(0, h, n_clutter[i])]
            )
            pixels = np.concatenate([uv[i, src], fake])
            source = np.concatenate([src, np.full(n_clutter[i], -1)]).astype(np.int64)
            perm = rng.permutation(len(pixels))
            frames.append(CameraFrameDetections(float(times[i]), k, pixels[perm], source[perm]))
    frames.sort(key=lambda f: (f.t, f.camera))
    return frames


RENDER_RATE_HZ = 5.0
TRACKING_MINUTES = 30.0


@dataclass(frozen=True)
class RenderedFrame:
    """One camera frame of the `tracking` scenario: its capture time (s), the index of its
    camera among the calibrated ones, and what detect_frame found in its image."""

    t: float
    camera: int
    found: tuple[FrameDetection, ...]


def rendered_frames(
    scene: Scene,
    seed: int,
    calibrated: CalibratedCameras,
    *,
    minutes: float = TRACKING_MINUTES,
    rate_hz: float = RENDER_RATE_HZ,
    exposure: ExposureChanges | None = None,
) -> tuple[list[RenderedFrame], Array]:
    """Return the `tracking` scenario's frames in capture order (every calibrated camera at
    `rate_hz` with its own phase, each image rendered with the robot patrolling and the
    walkers, and its detections) and the robot's drive (poses (N, 3) every 0.05 s).
    `exposure`: the cameras' exposure steps (None: a constant exposure)."""
    if scene.robot is None or scene.robot.marker is None:
        raise InvalidInput("the tracking scenario needs a robot with a top marker")
    rng = np.random.default_rng(seed)
    renderer = renderer_for(scene)
    cameras = calibrated.cameras
    duration = 60.0 * minutes
    drive = simulate_patrol(scene.robot, duration + 1.0, dt=0.05, rng=seed)
    pose = np.asarray(drive.pose)
    crowd = crowd_around(scene, pose)
    # The marker's size is the robot's specification, as its colour is.
    marker = MarkerDetectorConfig(
        colour=scene.robot.marker.colour, radius=scene.robot.marker.radius
    )
    mast = mast_config(scene.robot)
    people = {c.name: _background(renderer, scene, c.name) for c in scene.cameras}
    period = 1.0 / rate_hz
    schedule = []
    for k in range(len(cameras)):
        phase = rng.uniform(0.0, period)
        schedule += [(float(t), k) for t in np.arange(phase, duration, period)]
    schedule.sort()
    frames = []
    for t, k in schedule:
        spec = scene.cameras[calibrated.index[k]]
        where = crowd.positions([t])[0]
        walkers = tuple((float(x), float(y)) for x, y in where[1:])
        state = WorldState(t, Pose2D(*robot_poses(crowd, pose, np.array([t]))[0]), walkers)
        if exposure is None:
            image = renderer.render(spec.name, state, rng=rng).image
        else:
            noise = exposure.noise(spec.name, t)
            image = renderer.render(spec.name, state, rng=rng, noise=noise).image
        found = detect_frame(
            image,
            marker=marker,
            marker_height=scene.robot.marker.height,
            people=people[spec.name],
            camera=cameras[k],
            mast=mast,
        )
        frames.append(RenderedFrame(t, k, tuple(found)))
    return frames, np.asarray(drive.pose)


def mast_config(robot: Robot) -> MarkerDetectorConfig | None:
    """Return the detector settings of the robot's mast marker, None without one."""
    m = robot.mast_marker
    return None if m is None else MarkerDetectorConfig(colour=m.colour)


def _background(renderer: Renderer, scene: Scene, camera: str) -> PersonDetector:
    # The empty home, as an installer records it: no robot, nobody in view.
    away = tuple((1e4, 1e4) for _ in scene.people)
    detector = PersonDetector()
    for i in range(3):
        detector.learn(renderer.render(camera, WorldState(0.0, None, away), rng=i).image)
    return detector
