"""The robot's floor camera in the twin: its mount, its lens, and its own calibration.

The scene's robot carries one onboard camera, mounted level; spot following needs the floor
camera spec 07 describes (tilted down, seeing the floor from ~0.3 m ahead), so it is defined
here (`FLOOR_CAMERA_*`) until the scene schema carries it. Its intrinsics come from its own
Zhang calibration on rendered chessboard views (`floor_camera_intrinsics`, core.sim.intrinsics),
its plane from one rendered view of a floor chessboard on those intrinsics
(`calibrate_floor_camera`): no estimator reads the true lens (FLOOR_CAMERA_K,
FLOOR_CAMERA_DIST), which only forms the images.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.calibration import Chessboard, board_object_points, find_chessboard
from core.calibration.onboard import FloorPlane, calibrate_floor_plane
from core.errors import InvalidInput
from core.geometry.camera import project_points
from core.geometry.rotations import matrix_to_rotvec
from core.sim.intrinsics import NOISE as INTRINSICS_NOISE
from core.sim.intrinsics import RenderedCalibration, calibrate_from_board_views
from core.sim.render import Renderer, camera_at
from core.sim.render.landmarks import LandmarkCamera
from core.sim.scene import Board, CeilingCamera

Array = NDArray[np.float64]

# The floor camera on the robot (robot frame: x forward, y left, z up): 0.15 m ahead of the
# axle, 0.40 m up, pitched 40 degrees down; 640 x 480, f = 500 px, mild barrel distortion.
# It sees the floor from about 0.33 m to 1.7 m ahead of the axle.
FLOOR_CAMERA_POSITION = (0.15, 0.0, 0.40)
FLOOR_CAMERA_PITCH = math.radians(40.0)
FLOOR_CAMERA_K = np.array([[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]])
FLOOR_CAMERA_DIST = np.array([-0.05, 0.01, 0.0, 0.0, 0.0])
FLOOR_CAMERA_SIZE = (640, 480)
# The floor camera under-exposes, as a laser-spot camera is set to: the floor sits at mid-grey
# and the laser, far brighter than the room, saturates the red channel (on a bright tile at
# full exposure the spot is only ~40 grey levels redder than the floor, below the detector's
# threshold).
FLOOR_CAMERA_EXPOSURE = 0.5


def floor_camera_mount() -> Array:
    """Return T_robot_cam (4, 4) of the floor camera (OpenCV camera axes)."""
    c, s = math.cos(FLOOR_CAMERA_PITCH), math.sin(FLOOR_CAMERA_PITCH)
    z = np.array([c, 0.0, -s])
    x = np.array([0.0, -1.0, 0.0])
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = FLOOR_CAMERA_POSITION
    return T


def project_robot_points(T_robot_cam: Array, X_robot: Array) -> tuple[Array, NDArray[np.bool_]]:
    """Return (pixels (N, 2), in view (N,)) of robot-frame points in the floor camera."""
    T_cam_robot = np.linalg.inv(T_robot_cam)
    R, t = T_cam_robot[:3, :3], T_cam_robot[:3, 3]
    proj = project_points(X_robot, matrix_to_rotvec(R), t, FLOOR_CAMERA_K, FLOOR_CAMERA_DIST)
    w, h = FLOOR_CAMERA_SIZE
    uv = proj.points
    ok = (proj.depth > 0.05) & (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0)
    ok &= uv[:, 1] <= h - 1
    return uv, ok


# The floor pattern the floor camera is calibrated on: a chessboard of 0.1 m squares, 7 x 6
# inner corners (7 + 6 odd: its first corner is told from its last), laid flat 0.5 m to 1.1 m
# ahead of the robot, centred on its axis; the robot stands at FLOOR_PATTERN_POSE (world x, y,
# theta), where the living room's floor is free ahead of it.
FLOOR_PATTERN = Board(inner_corners=(7, 6), square_size=0.1, margin=0.5)
FLOOR_PATTERN_POSE = (1.6, 1.2, 0.0)


def robot_transform(pose: ArrayLike) -> Array:
    """Return T_world_robot (4, 4) of a base pose (x, y, theta)."""
    x, y, th = (float(v) for v in np.asarray(pose, dtype=np.float64).ravel()[:3])
    c, s = math.cos(th), math.sin(th)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:2, 3] = [x, y]
    return T


def floor_camera_at(pose: ArrayLike) -> CeilingCamera:
    """Return the floor camera of a robot at base pose (x, y, theta) as a renderable camera."""
    T = robot_transform(pose) @ floor_camera_mount()
    return camera_at("floor_camera", FLOOR_CAMERA_K, FLOOR_CAMERA_DIST, FLOOR_CAMERA_SIZE, T)


def _floor_pattern_points() -> tuple[Array, Array]:
    """Return (T_robot_board (4, 4), inner corners (N, 3) robot frame, detector order)."""
    cols, rows = FLOOR_PATTERN.inner_corners
    s = FLOOR_PATTERN.square_size
    # Columns run ahead (+x), rows to the right (-y): z = x cross y points down, the printed
    # face looks up. The print is drawn 0.5 mm above the floor (its thickness), its corners
    # taken on the floor.
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = [0.5, (rows - 1) * s / 2, 0.0]
    P = board_object_points(Chessboard(cols, rows), s) @ T[:3, :3].T + T[:3, 3]
    T[2, 3] = 5e-4
    return T, P


def floor_camera_intrinsics(rng: np.random.Generator) -> RenderedCalibration:
    """Return the floor camera's intrinsics as the robot's owner gets them: Zhang from
    rendered chessboard views through the floor camera's lens (core.sim.intrinsics)."""
    w, h = FLOOR_CAMERA_SIZE
    return calibrate_from_board_views(
        LandmarkCamera(FLOOR_CAMERA_K, FLOOR_CAMERA_DIST, w, h), rng, noise=INTRINSICS_NOISE
    )


def calibrate_floor_camera(
    rng: np.random.Generator,
    renderer: Renderer | None = None,
    intrinsics: RenderedCalibration | None = None,
) -> FloorPlane:
    """Return the floor camera's floor plane from one view of the floor pattern
    (FLOOR_PATTERN) laid ahead of the robot, on the camera's calibrated intrinsics
    (`intrinsics`, default: calibrated first from rendered chessboard views,
    floor_camera_intrinsics; never the twin's true lens). With a `renderer`, the view is
    rendered (the robot at FLOOR_PATTERN_POSE in the home) and the corners detected
    (core.calibration.find_chessboard); without one, the corners' true pixels plus 0.1 px of
    noise (what cv2.cornerSubPix achieves on chessboard corners). Raises PatternNotFound when
    the rendered pattern is not found."""
    cal = intrinsics if intrinsics is not None else floor_camera_intrinsics(rng)
    T_robot_board, pattern = _floor_pattern_points()
    if renderer is None:
        uv, ok = project_robot_points(floor_camera_mount(), pattern)
        if not np.all(ok):
            raise InvalidInput("the floor pattern must lie inside the floor camera's view")
        uv = uv + rng.normal(0.0, 0.1, uv.shape)
        return calibrate_floor_plane(pattern, uv, cal.K, cal.dist, sigma=0.1)
    T_world_robot = robot_transform(FLOOR_PATTERN_POSE)
    frame = renderer.render_board(
        floor_camera_at(FLOOR_PATTERN_POSE), FLOOR_PATTERN, T_world_robot @ T_robot_board, rng=rng
    )
    uv = find_chessboard(frame.image, FLOOR_PATTERN.inner_corners).corners
    return calibrate_floor_plane(pattern, uv, cal.K, cal.dist)
