"""The twin's camera model, sensor-noise options and rendered frames (public records)."""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import InvalidInput
from core.geometry.camera import project_points
from core.geometry.rotations import matrix_to_quaternion, matrix_to_rotvec
from core.sim._geometry import pose_matrix
from core.sim.motion import Pose2D
from core.sim.scene import CeilingCamera, Distortion, Intrinsics, Pose

Array = NDArray[np.float64]
Image = NDArray[Any]  # uint8 images; typed loosely because cv2 returns its own array type

# --------------------------------------------------------------------------------------------
# Public results and options


@dataclass(frozen=True, eq=False)
class CameraModel:
    """A ceiling camera ready for projection.

    K (3, 3) pixels; dist (5,) OpenCV order (k1, k2, p1, p2, k3); R_world_camera (3, 3) and
    position (3,) metres give the pose T_world_camera (camera frame: x right, y down, z forward).
    """

    name: str
    width: int
    height: int
    K: Array
    dist: Array
    R_world_camera: Array
    position: Array
    frame_rate: float

    @property
    def T_world_camera(self) -> Array:
        """Return the 4x4 pose mapping camera coordinates to world coordinates."""
        T = np.eye(4)
        T[:3, :3] = self.R_world_camera
        T[:3, 3] = self.position
        return T

    @property
    def R_camera_world(self) -> Array:
        """Return the rotation (3, 3) mapping world directions to camera directions."""
        return self.R_world_camera.T

    @property
    def t_camera_world(self) -> Array:
        """Return the translation (3,) of T_camera_world: Xc = R_camera_world X + t."""
        return -self.R_world_camera.T @ self.position

    @property
    def rvec(self) -> Array:
        """Return the rotation vector (3,) of R_camera_world (cv2.projectPoints' rvec)."""
        return matrix_to_rotvec(self.R_camera_world)

    @property
    def quaternion_xyzw(self) -> Array:
        """Return the orientation of T_world_camera as a quaternion (x, y, z, w)."""
        return matrix_to_quaternion(self.R_world_camera)

    def project(self, points: ArrayLike) -> Array:
        """Return the distorted pixels (N, 2) of world points (N, 3) metres."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return project_points(p, self.rvec, self.t_camera_world, self.K, self.dist).points

    def depth(self, points: ArrayLike) -> Array:
        """Return the camera-frame z (N,) metres of world points (N, 3); < 0 is behind."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return (p - self.position) @ self.R_world_camera[:, 2]


def camera_model(camera: CeilingCamera) -> CameraModel:
    """Return the CameraModel of a scene camera."""
    R, pos = pose_matrix(camera.pose)
    return CameraModel(
        name=camera.name,
        width=camera.resolution[0],
        height=camera.resolution[1],
        K=np.array(camera.intrinsics.matrix(), dtype=np.float64),
        dist=np.array(camera.distortion.opencv(), dtype=np.float64),
        R_world_camera=R,
        position=pos,
        frame_rate=camera.frame_rate,
    )


def camera_at(
    name: str,
    K: ArrayLike,
    dist: ArrayLike,
    size: tuple[int, int],
    T_world_camera: ArrayLike,
    frame_rate: float = 15.0,
) -> CeilingCamera:
    """Return a camera that is not one of the scene's (one that moves: on the robot, on the
    arm) as a renderable camera: intrinsics K (3, 3), distortion (k1, k2, p1, p2, k3), image
    size (width, height) and its pose T_world_camera (4, 4, OpenCV camera axes)."""
    Km = np.asarray(K, dtype=np.float64)
    k1, k2, p1, p2, k3 = (float(v) for v in np.asarray(dist, dtype=np.float64).ravel()[:5])
    T = np.asarray(T_world_camera, dtype=np.float64)
    qx, qy, qz, qw = (float(v) for v in matrix_to_quaternion(T[:3, :3]))
    return CeilingCamera(
        name=name,
        resolution=(int(size[0]), int(size[1])),
        intrinsics=Intrinsics(
            fx=float(Km[0, 0]), fy=float(Km[1, 1]), cx=float(Km[0, 2]), cy=float(Km[1, 2])
        ),
        distortion=Distortion(k1=k1, k2=k2, k3=k3, p1=p1, p2=p2),
        pose=Pose(
            position=(float(T[0, 3]), float(T[1, 3]), float(T[2, 3])),
            quaternion_xyzw=(qx, qy, qz, qw),
        ),
        frame_rate=frame_rate,
    )


@dataclass(frozen=True)
class SensorNoise:
    """Image degradation, applied after the lens: Gaussian blur of `blur_sigma` pixels, gain
    `gain` (times a per-frame factor 1 + gain_jitter N(0, 1)), then additive Gaussian noise of
    standard deviation `sigma` grey levels, rounded and saturated to 0..255.

    For speed the noise of a frame is a window, at a random offset drawn from the frame's
    generator, into a fixed bank of Gaussian samples held by the renderer; each pixel's noise
    is N(0, sigma^2) (rounded to an integer) and differs between seeds and frames.
    """

    sigma: float = 2.0
    blur_sigma: float = 0.5
    gain: float = 1.0
    gain_jitter: float = 0.0

    def __post_init__(self) -> None:
        for name in ("sigma", "blur_sigma", "gain", "gain_jitter"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise InvalidInput(f"SensorNoise.{name} must be finite and >= 0, got {v}")


@dataclass(frozen=True)
class ExposureChanges:
    """A ceiling camera's exposure stepping as an automatic exposure does (a scenario option;
    off unless given). At random times, a Poisson process of mean interval `interval` seconds
    from t = 0, the gain is multiplied by 1 + s, |s| uniform in `step` (0.1-0.3: the steps of
    consumer cameras' automatic exposure), the sign random, except that it is taken towards 1
    when the gain would leave [1 / limit, limit]. Each camera steps on its own: its steps are
    drawn from (`seed`, the camera's name)."""

    interval: float = 60.0
    step: tuple[float, float] = (0.1, 0.3)
    limit: float = 1.6
    seed: int = 0

    def __post_init__(self) -> None:
        lo, hi = self.step
        if not (math.isfinite(self.interval) and self.interval > 0):
            raise InvalidInput(f"interval must be > 0 seconds, got {self.interval}")
        if not 0 <= lo <= hi < 1:
            raise InvalidInput(
                f"step must be (low, high) with 0 <= low <= high < 1, got {self.step}"
            )
        if not (math.isfinite(self.limit) and self.limit > 1 + hi):
            raise InvalidInput(f"limit must exceed 1 + the largest step, got {self.limit}")

    def steps(self, camera: str, until: float) -> tuple[Array, Array]:
        """Return the times (K,) s of camera `camera`'s exposure steps up to `until` (s) and its
        gain after each (K,)."""
        n = 64
        while True:
            times, gains = _exposure_steps(self, camera, n)
            if times[-1] > until:
                break
            n *= 2
        k = int(np.searchsorted(times, until, side="right"))
        return times[:k], gains[:k]

    def gain(self, camera: str, t: float) -> float:
        """Return camera `camera`'s exposure gain at time `t` (s; 1 before its first step)."""
        _, gains = self.steps(camera, t)
        return float(gains[-1]) if len(gains) else 1.0

    def noise(self, camera: str, t: float, base: SensorNoise | None = None) -> SensorNoise:
        """Return `base` (default SensorNoise()) with its gain times the camera's at `t`."""
        b = base or SensorNoise()
        return replace(b, gain=b.gain * self.gain(camera, t))


@lru_cache(maxsize=64)
def _exposure_steps(changes: ExposureChanges, camera: str, n: int) -> tuple[Array, Array]:
    """Return the times (n,) s of a camera's first `n` exposure steps and its gain after each."""
    rng = np.random.default_rng([changes.seed, zlib.crc32(camera.encode())])
    times = np.cumsum(rng.exponential(changes.interval, n))
    size = rng.uniform(*changes.step, n)
    sign = rng.choice([-1.0, 1.0], n)
    gains = np.empty(n)
    g = 1.0
    for k in range(n):  # each step depends on the gain before it
        s = sign[k] * size[k]
        if not 1.0 / changes.limit <= g * (1.0 + s) <= changes.limit:
            s = -s
        g *= 1.0 + s
        gains[k] = g
    return times, gains


@dataclass(frozen=True, eq=False)
class Frame:
    """One rendered image with its ground truth (the truth is for tests and scoring only).

    image: (H, W, 3) uint8 BGR. camera: the camera that took it (K, dist, T_world_camera).
    robot: the robot's true pose (None: no robot). people: walkers' floor positions (x, y).
    marker_world (3,) metres: the marker disc's centre; marker_pixel (2,): its projection with
    distortion; marker_ellipse_pixel (2,): the centre of the disc's image ellipse in the ideal
    image (the area centroid of the projected disc, which is not the projection of the disc's
    centre), mapped through the distortion; marker_visible: inside the image, in front of the
    camera and not hidden by the static scene or the board, centre and whole rim.
    mast_marker_ellipse_pixel, mast_marker_visible: the same for the mast marker's disc.
    board_corners_world (N, 3) and
    board_corner_pixels (N, 2): the chessboard's inner corners, row by row of the board
    (columns fastest); board_visible: all corners in front of the camera, inside the image, on
    the board's front side and unoccluded by the static scene. gain: the exposure gain this
    frame was taken with. spot_pixel (2,): the laser spot's projection with distortion;
    spot_visible: in front of the camera, inside the image and not hidden.
    """

    image: Image
    camera: CameraModel
    time: float
    robot: Pose2D | None
    people: tuple[tuple[float, float], ...]
    marker_world: Array | None = None
    marker_pixel: Array | None = None
    marker_ellipse_pixel: Array | None = None
    marker_visible: bool = False
    mast_marker_ellipse_pixel: Array | None = None
    mast_marker_visible: bool = False
    board_corners_world: Array | None = None
    board_corner_pixels: Array | None = None
    board_visible: bool = False
    gain: float = field(default=1.0)
    spot_pixel: Array | None = None
    spot_visible: bool = False
