"""What a camera sees of world points: inside its image, not hidden by what is drawn so far (the
z-buffer), all of them at once, and the distorted image of a disc's centre (the ground truth of
a marker's ellipse)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from core.geometry.camera import distort_normalized
from core.sim.render._camera import CameraModel
from core.sim.render._raster import Array, _Target


def _in_image(cam: CameraModel, px: Array) -> NDArray[np.bool_]:
    """Return whether pixels (N, 2) lie inside the camera's image."""
    return (
        (px[:, 0] >= 0)
        & (px[:, 0] <= cam.width - 1)
        & (px[:, 1] >= 0)
        & (px[:, 1] <= cam.height - 1)
    )


def _unoccluded(tgt: _Target, X: Array, tol: float = 0.0) -> NDArray[np.bool_]:
    """Return whether world points (N, 3) lie in front of tgt's z-buffer (+ tol metres)."""
    Pc = tgt.to_camera(X)
    uv = np.rint(tgt.to_pixels(Pc)).astype(int)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < tgt.w) & (uv[:, 1] >= 0) & (uv[:, 1] < tgt.h)
    uvc = np.clip(uv, 0, [tgt.w - 1, tgt.h - 1])
    return inside & (Pc[:, 2] <= tgt.depth[uvc[:, 1], uvc[:, 0]] + tol)


def _disc_image_centre(cam: CameraModel, centre: Array, radius: float) -> Array:
    """Return the distorted pixel (2,) of the centre of a horizontal disc's image ellipse.

    The disc x^2 + y^2 <= r^2 in its plane maps by H = K [R e1, R e2, R c + t] to the conic
    C' = H^-T diag(1, 1, -r^2) H^-1 (Hartley & Zisserman eq. 2.13), whose centre -A^-1 b (A its
    upper-left 2x2 block, b its last column's top) is the area centroid of the ideal image of
    the disc; it is mapped through the lens distortion like any ideal point.
    """
    H = cam.K @ np.stack(
        [
            cam.R_camera_world[:, 0],
            cam.R_camera_world[:, 1],
            cam.R_camera_world @ centre + cam.t_camera_world,
        ],
        1,
    )
    Hi = np.linalg.inv(H)
    C = Hi.T @ np.diag([1.0, 1.0, -(radius**2)]) @ Hi
    c = -np.linalg.solve(C[:2, :2], C[:2, 2])
    xn = np.linalg.solve(cam.K, np.array([c[0], c[1], 1.0]))
    xd = distort_normalized(xn[:2] / xn[2], cam.dist)
    return (cam.K @ np.array([xd[0], xd[1], 1.0]))[:2]


def _all_seen(cam: CameraModel, tgt: _Target, X: Array) -> bool:
    """Return whether the camera sees all the world points (N, 3): in front of the near plane,
    inside the image and not hidden by tgt's z-buffer."""
    return bool(
        np.all(cam.depth(X) > tgt.near)
        and np.all(_in_image(cam, cam.project(X)))
        and np.all(_unoccluded(tgt, X))
    )
