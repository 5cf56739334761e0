"""The robot's onboard (floor) camera: its floor plane from one view, spots back-projected on it.

Extrinsics from one view of a floor pattern whose points lie at known positions (X, Y, 0) in
the robot frame (x forward, y left, z up, origin on the floor under the axle): the world-plane
homography H ~ K [r1 r2 t] of the pattern (spec 01), decomposed with the known intrinsics
(Zhang 2000, sec. 3.1) and refined by LM on the reprojection error
(core.calibration.pose.estimate_plane_pose), gives T_cam_robot = [R | t]. The floor is the
plane Z = 0 of that frame, so in camera coordinates its unit normal is n_c = R e_z and it lies
at distance d_c = n_c . t from the optical centre: points X_c on the floor satisfy
n_c . X_c = d_c (H&Z sec. 8.3 for the plane through the pattern).

A spot at pixel x back-projects along the ray m = K^-1 x (undistorted), X_c = d_c m / (n_c . m)
(the ray-plane intersection, H&Z eq. 6.14), and into the robot frame by T_robot_cam.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_matrix, as_points
from core.calibration.pose import estimate_plane_pose
from core.errors import DegenerateConfiguration, InvalidInput
from core.geometry.camera import as_distortion, undistort_points

Array = NDArray[np.float64]


@dataclass(frozen=True)
class FloorPlane:
    """The onboard camera's floor: unit normal `normal` (3,) in camera coordinates, pointing
    from the optical centre towards the floor, and its distance `distance` (m) > 0 from the
    centre, n . X_c = d for floor points; `T_robot_cam` (4, 4) the camera's
    pose in the robot frame; `K` (3, 3) and `dist` (5,) the intrinsics used; `rms` px of the
    fit; `covariance` (6, 6) of the pattern pose (rvec, t) it came from."""

    normal: Array
    distance: float
    T_robot_cam: Array
    K: Array
    dist: Array
    rms: float
    covariance: Array = field(repr=False)

    def back_project(self, pixels: ArrayLike) -> Array:
        """Return the floor points (N, 3) in camera coordinates of pixels (N, 2) (distorted).

        Rays that do not meet the floor in front of the camera (n . m <= 0: the pixel is at or
        above the floor's horizon) give NaN rows.
        """
        px = as_points(pixels, 2, "pixels")
        m = undistort_points(px, self.K, self.dist)
        rays = np.column_stack([m, np.ones(len(m))])
        den = rays @ self.normal
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = np.where(den > 1e-12, self.distance / den, np.nan)
        out: Array = rays * lam[:, None]
        return out

    def to_robot(self, pixels: ArrayLike) -> Array:
        """Return the floor points (N, 2) in the robot frame (x forward, y left, metres) of
        pixels (N, 2); NaN rows for pixels above the horizon."""
        Xc = self.back_project(pixels)
        Xr = Xc @ self.T_robot_cam[:3, :3].T + self.T_robot_cam[:3, 3]
        return Xr[:, :2]


def calibrate_floor_plane(
    pattern_points: ArrayLike,
    image_points: ArrayLike,
    K: ArrayLike,
    dist: ArrayLike | None = None,
    *,
    sigma: float | None = None,
) -> FloorPlane:
    """Return the floor plane of the onboard camera from one view of a floor pattern.

    pattern_points: (N, 2) or (N, 3) with Z = 0, the pattern's points in the robot frame
    (metres); image_points: (N, 2) their pixels; K: (3, 3) intrinsics (Zhang, spec 01); dist:
    OpenCV distortion, held fixed. N >= 4, not collinear. Minimises the reprojection error over
    the 6-dof pose (estimate_plane_pose). Raises NotEnoughPoints, InvalidInput,
    DegenerateConfiguration (collinear points, the floor seen edge-on).
    """
    Km = as_matrix(K, (3, 3), "K")
    est = estimate_plane_pose(pattern_points, image_points, Km, dist, sigma=sigma)
    R, t = est.R, est.t
    n = R[:, 2].copy()
    d = float(n @ t)
    if d < 0:
        n, d = -n, -d
    if d < 1e-6:
        raise DegenerateConfiguration(
            "the floor passes through the camera centre; the pattern's pose is wrong"
        )
    T_cam_robot = np.eye(4)
    T_cam_robot[:3, :3], T_cam_robot[:3, 3] = R, t
    return FloorPlane(
        normal=n,
        distance=d,
        T_robot_cam=np.asarray(np.linalg.inv(T_cam_robot), dtype=np.float64),
        K=Km,
        dist=as_distortion(dist),
        rms=est.rms,
        covariance=est.covariance,
    )


def floor_plane_from_mount(
    T_robot_cam: ArrayLike, K: ArrayLike, dist: ArrayLike | None = None
) -> FloorPlane:
    """Return the floor plane of a camera with a known pose in the robot frame (floor Z = 0)."""
    T = as_matrix(T_robot_cam, (4, 4), "T_robot_cam")
    R = T[:3, :3]
    if np.max(np.abs(R.T @ R - np.eye(3))) > 1e-6:
        raise InvalidInput("T_robot_cam's rotation must be orthonormal")
    Tinv = np.linalg.inv(T)
    n = Tinv[:3, 2].copy()
    d = float(n @ Tinv[:3, 3])
    if d < 0:
        n, d = -n, -d
    return FloorPlane(
        normal=np.asarray(n, dtype=np.float64),
        distance=d,
        T_robot_cam=T.copy(),
        K=as_matrix(K, (3, 3), "K"),
        dist=as_distortion(dist),
        rms=0.0,
        covariance=np.zeros((6, 6)),
    )
