"""The landmark robot's head camera on the twin (spec 07: on the pan-tilt unit at about 1.1 m,
640x480): which camera it is (`head_camera`), its own calibration (`calibrate_head_camera`:
Zhang on rendered chessboard views; no estimate reads its true intrinsics), its pose on the
robot at given pan and tilt (`robot_head_pose`), and the distance it reads a landmark from
(`reading_standoff`).

The camera is the scene robot's head camera (or its onboard camera) when the scene gives one,
else `HEAD_CAMERA` (600 px focal length, 56 deg horizontal field, barrel distortion).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from core.landmarks.artwork import pattern_layout
from core.sim._geometry import yaw_matrix
from core.sim.intrinsics import NOISE, calibrate_from_board_views
from core.sim.render.landmarks import LandmarkCamera
from core.sim.scene import CameraMount, HeadCamera, Scene

Array = NDArray[np.float64]

HEAD_CAMERA = LandmarkCamera(
    np.array([[600.0, 0.0, 321.5], [0.0, 600.0, 242.0], [0.0, 0.0, 1.0]]),
    np.array([-0.12, 0.05, 0.001, -0.0005, 0.0]),
    640,
    480,
)
SIZES = {"object": 0.10, "signpost": 0.20}
CALIBRATION_VIEWS = 12


def head_camera(scene: Scene | None) -> tuple[LandmarkCamera, str]:
    """Return the true head camera: the scene robot's head camera, else its onboard camera,
    else HEAD_CAMERA."""
    robot = None if scene is None else scene.robot
    mount: HeadCamera | CameraMount | None = None
    source = "scene robot"
    if robot is not None:
        mount = robot.head_camera
        if mount is None:
            mount, source = robot.onboard_camera, "scene robot's onboard camera"
    if mount is None:
        return HEAD_CAMERA, "default head camera (600 px, 640x480)"
    K = np.array(mount.intrinsics.matrix(), dtype=np.float64)
    w, h = mount.resolution
    return LandmarkCamera(K, np.array(mount.distortion.opencv()), int(w), int(h)), source


def calibrate_head_camera(
    cam: LandmarkCamera, rng: np.random.Generator, views: int = CALIBRATION_VIEWS
) -> tuple[Array, Array, float]:
    """Return (K, dist, rms px) of the camera calibrated from rendered chessboard views
    (core.sim.intrinsics)."""
    cal = calibrate_from_board_views(cam, rng, views, NOISE)
    return cal.K, cal.dist, cal.rms


def calibrate_scene_head_camera(
    scene: Scene, rng: np.random.Generator, views: int = CALIBRATION_VIEWS
) -> tuple[Array, Array, float]:
    """Return (K, dist, rms px) of the scene's head camera (head_camera) calibrated from
    rendered chessboard views."""
    cam, _ = head_camera(scene)
    return calibrate_head_camera(cam, rng, views)


# Camera axes at pan = tilt = 0 in the robot frame: z forward (+x), x right (-y), y down (-z).
_R_ROBOT_CAM0 = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
# QR modules the controller assumes before a symbol is read (version 5: 37 modules, payloads
# up to 84 bytes at level M); the reading distance puts such a module on READ_MODULE_PX pixels.
READ_MODULES = 37
READ_MODULE_PX = 3.3
MIN_STANDOFF = 0.22  # m: camera-to-face horizontal distance at the reading pose, at least


def _ry(a: float) -> Array:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def robot_head_pose(head: HeadCamera, pan: float, tilt: float) -> Array:
    """Return T_robot_cam (4, 4) of the head camera at joint angles pan, tilt (radians)."""
    T = np.eye(4)
    T[:3, :3] = yaw_matrix(pan) @ _ry(tilt) @ _R_ROBOT_CAM0
    T[:3, 3] = head.position
    return T


def reading_standoff(kind: str, focal_px: float, dz: float) -> float:
    """Return the reading pose's horizontal distance d (m) from the camera to a vertical face
    whose centre lies dz metres below the camera: the farthest d at which a nominal module
    (READ_MODULES across the symbol) spans READ_MODULE_PX along the foreshortened axis,
    f m d / (d^2 + dz^2) = px (a quadratic in d), else d = |dz| (45 deg, where that span
    peaks); at least MIN_STANDOFF."""
    a = focal_px * pattern_layout(kind, SIZES[kind]).qr_side / READ_MODULES
    disc = a**2 - 4 * READ_MODULE_PX**2 * dz**2
    d = (a + np.sqrt(disc)) / (2 * READ_MODULE_PX) if disc >= 0 else abs(dz)
    return float(max(d, MIN_STANDOFF))
