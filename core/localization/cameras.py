"""The description of one calibrated camera of the network, as the floor estimators need it.

A `NetworkCamera` holds what calibration (spec 02, section 1) produces for one ceiling camera:
the intrinsic matrix K, OpenCV's distortion coefficients (5, 8, 12 or 14), the pose and the
image size.
The pose is stored world-to-camera, Xc = R X + t (R = R_camera_world, t = t_camera_world), the
form the projection uses; `from_pose` and `T_world_camera` convert from and to the camera's pose
in the world frame, T_world_camera = [[R^T, -R^T t], [0, 1]].

Frames: world right-handed, Z up, the floor Z = 0; camera frame OpenCV (x right, y down,
z forward). Pixels: origin at the centre of the top-left pixel.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_matrix, as_points
from core.errors import ConvergenceError, InvalidInput
from core.geometry.camera import as_distortion_model, project_points, undistort_points
from core.geometry.rotations import matrix_to_rotvec

Array = NDArray[np.float64]

# Orthonormality tolerance of a rotation matrix given by a caller (max |R^T R - I|).
_ROTATION_TOL = 1e-6
# Samples per image side used to find the field-of-view radius in normalised coordinates.
_BORDER_SAMPLES = 64


@dataclass(frozen=True, eq=False)
class NetworkCamera:
    """A calibrated camera: intrinsics, distortion, world-to-camera pose and image size.

    K: (3, 3) upper triangular, K[2, 2] = 1, fx, fy > 0 (pixels). dist: (5,) OpenCV
    (k1, k2, p1, p2, k3), fewer coefficients padded with zeros; or (14,) for OpenCV's 8, 12 or 14
    (core.geometry.camera.as_distortion_model). R: (3, 3) = R_camera_world.
    t: (3,) = t_camera_world (metres), so Xc = R X + t. image_size: (width, height) in pixels, or
    None when unknown (then `in_view` only tests that a point is in front of the camera).
    Derived on construction: `rvec` (3,), the rotation vector of R (for core.geometry.camera),
    and `fov_radius`, the largest ideal normalised radius inside the image (`in_view`).
    """

    K: Array
    dist: Array
    R: Array
    t: Array
    image_size: tuple[int, int] | None = None
    name: str = ""
    rvec: Array = field(init=False, repr=False)
    fov_radius: float = field(init=False, repr=False)

    def __post_init__(self) -> None:
        K = as_matrix(self.K, (3, 3), "K")
        if abs(K[2, 2]) < 1e-300:
            raise InvalidInput("K[2, 2] must be non-zero (normally 1)")
        K = K / K[2, 2]
        if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise InvalidInput(
                "K must be upper triangular with positive focal lengths [[fx, s, cx], "
                f"[0, fy, cy], [0, 0, 1]], got {K.tolist()}"
            )
        d = as_distortion_model(self.dist)
        R = as_matrix(self.R, (3, 3), "R (R_camera_world)")
        if np.max(np.abs(R.T @ R - np.eye(3))) > _ROTATION_TOL or np.linalg.det(R) <= 0:
            raise InvalidInput(
                "R must be a rotation (orthonormal, det +1); re-orthonormalise it, e.g. with "
                "core.geometry.rotations.nearest_rotation"
            )
        t = as_matrix(self.t, (3,), "t (t_camera_world)")
        size = self.image_size
        if size is not None:
            if len(size) != 2 or int(size[0]) <= 0 or int(size[1]) <= 0:
                raise InvalidInput(f"image_size must be (width, height) > 0, got {size}")
            size = (int(size[0]), int(size[1]))
        for name, value in (("K", K), ("dist", d), ("R", R), ("t", t)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "image_size", size)
        # Through a batch of one: the unbatched call fails for rotations by exactly pi (a
        # camera looking straight down), which the batched one handles.
        rvec = matrix_to_rotvec(R[None])[0]
        rvec.setflags(write=False)
        object.__setattr__(self, "rvec", rvec)
        object.__setattr__(self, "fov_radius", _fov_radius(K, d, size))

    @classmethod
    def from_pose(
        cls,
        K: ArrayLike,
        dist: ArrayLike | None,
        T_world_camera: ArrayLike,
        image_size: tuple[int, int] | None = None,
        name: str = "",
    ) -> NetworkCamera:
        """Return the camera whose pose in the world is T_world_camera (4x4, camera to world)."""
        T = as_matrix(T_world_camera, (4, 4), "T_world_camera")
        if np.max(np.abs(T[3] - [0.0, 0.0, 0.0, 1.0])) > 1e-12:
            raise InvalidInput("T_world_camera must have the last row (0, 0, 0, 1)")
        R = T[:3, :3].T
        return cls(
            K=np.asarray(K, dtype=np.float64),
            dist=np.zeros(5) if dist is None else np.asarray(dist, dtype=np.float64),
            R=R,
            t=-R @ T[:3, 3],
            image_size=image_size,
            name=name,
        )

    @classmethod
    def looking_at(
        cls,
        K: ArrayLike,
        dist: ArrayLike | None,
        position: ArrayLike,
        target: ArrayLike,
        image_size: tuple[int, int] | None = None,
        name: str = "",
    ) -> NetworkCamera:
        """Return a camera at `position` (world, m) whose optical axis passes through `target`.

        The image x axis is kept horizontal (perpendicular to world Z), so the image is upright:
        z_cam = (target - position) / |.|, x_cam = z_cam x Z / |.|, y_cam = z_cam x x_cam.
        Raises InvalidInput when the camera looks straight up or down (x_cam is undefined).
        """
        c = as_matrix(position, (3,), "position")
        z = as_matrix(target, (3,), "target") - c
        if np.linalg.norm(z) == 0:
            raise InvalidInput("target must differ from position")
        z = z / np.linalg.norm(z)
        x = np.cross(z, [0.0, 0.0, 1.0])
        if np.linalg.norm(x) < 1e-9:
            raise InvalidInput(
                "the camera looks vertically; give the pose with from_pose to fix its heading"
            )
        x = x / np.linalg.norm(x)
        y = np.cross(z, x)
        T = np.eye(4)
        T[:3, :3] = np.column_stack([x, y, z])
        T[:3, 3] = c
        return cls.from_pose(K, dist, T, image_size=image_size, name=name)

    @property
    def center(self) -> Array:
        """Return the optical centre in the world frame (3,), metres: C = -R^T t."""
        return -self.R.T @ self.t

    @property
    def T_world_camera(self) -> Array:
        """Return the camera's pose in the world (4, 4): maps camera coordinates to world."""
        T = np.eye(4)
        T[:3, :3] = self.R.T
        T[:3, 3] = self.center
        return T

    def project(self, points: ArrayLike) -> Array:
        """Return the pixels (N, 2) of world points (N, 3) (distortion included)."""
        X = as_points(points, 3, "points")
        return project_points(X, self.rvec, self.t, self.K, self.dist).points

    def in_view(self, points: ArrayLike) -> NDArray[np.bool_]:
        """Return whether world points (N, 3) are imaged: in front and inside the image.

        Inside means within [-0.5, width - 0.5] x [-0.5, height - 0.5] (pixel edges) and, so
        that the distortion polynomial cannot fold a point from outside the field of view back
        into the image, with an ideal normalised radius not beyond `fov_radius`, the largest
        radius of the undistorted image border.
        """
        X = as_points(points, 3, "points")
        Xc = X @ self.R.T + self.t
        front = Xc[:, 2] > 0
        if self.image_size is None:
            return front
        z = np.where(front, Xc[:, 2], 1.0)
        r2 = (Xc[:, 0] ** 2 + Xc[:, 1] ** 2) / z**2
        uv = project_points(X, self.rvec, self.t, self.K, self.dist).points
        w, h = self.image_size
        inside = (
            (uv[:, 0] >= -0.5) & (uv[:, 0] <= w - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= h - 0.5)
        )
        return front & inside & (r2 <= self.fov_radius**2)


def _fov_radius(K: Array, dist: Array, size: tuple[int, int] | None) -> float:
    """Return the largest ideal normalised radius of the image border (inf when unknown).

    The largest radius over the undistorted image is reached on its border (the maximum of a norm
    over a compact set lies on the boundary), so sampling the border bounds every visible ray.
    """
    if size is None:
        return float("inf")
    w, h = size
    s = np.linspace(0.0, 1.0, _BORDER_SAMPLES)
    xs = -0.5 + s * w
    ys = -0.5 + s * h
    border = np.concatenate(
        [
            np.column_stack([xs, np.full_like(xs, -0.5)]),
            np.column_stack([xs, np.full_like(xs, h - 0.5)]),
            np.column_stack([np.full_like(ys, -0.5), ys]),
            np.column_stack([np.full_like(ys, w - 0.5), ys]),
        ]
    )
    try:
        xy = undistort_points(border, K, dist)
    except ConvergenceError:
        return float("inf")
    # A small margin so that points on the border itself are not lost to rounding.
    return float(np.max(np.hypot(xy[:, 0], xy[:, 1]))) * (1.0 + 1e-9)
