"""Placing the PETS camera from the ground truth's floor points (what the placement endpoint
will do): a pinhole with square pixels and a centred principal point, focal length and pose by
least squares."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import minimize_scalar

from bench.pets_clip import SIZE, Array, Truth


@dataclass(frozen=True)
class Placement:
    """A pinhole camera placed from floor points: K, T_world_camera and the reprojection
    errors (px) of the points."""

    K: Array
    T_world_camera: Array
    errors: Array


def place_camera(truth: Truth, size: tuple[int, int] = SIZE) -> Placement:
    """Return the camera that best reprojects the ground truth's floor points (the bottom
    centre of each counted box, at its world position): square pixels, principal point at the
    image centre, no distortion; the focal length by a bounded scalar search around
    cv2.solvePnP's pose (iterative, least squares)."""
    keep = truth.conf == 1
    pixels = np.column_stack(
        [0.5 * (truth.box[keep, 0] + truth.box[keep, 2]), truth.box[keep, 3]]
    ).astype(np.float64)
    world = np.column_stack([truth.world[keep], np.zeros(int(keep.sum()))]).astype(np.float64)
    cx, cy = (size[0] - 1) / 2.0, (size[1] - 1) / 2.0

    def solve(f: float) -> tuple[Array, Array, Array]:
        K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
        ok, rvec, tvec = cv2.solvePnP(world, pixels, K, None, flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok:
            raise RuntimeError("solvePnP failed on the floor points")
        projected, _ = cv2.projectPoints(world, rvec, tvec, K, None)
        err = np.linalg.norm(projected.reshape(-1, 2) - pixels, axis=1)
        return K, np.hstack([rvec.ravel(), tvec.ravel()]), err

    best = minimize_scalar(
        lambda f: float(np.mean(solve(f)[2] ** 2)), bounds=(300.0, 5000.0), method="bounded"
    )
    K, pose, err = solve(float(best.x))
    R, _ = cv2.Rodrigues(pose[:3])
    T_camera_world = np.eye(4)
    T_camera_world[:3, :3] = R
    T_camera_world[:3, 3] = pose[3:]
    return Placement(K=K, T_world_camera=np.linalg.inv(T_camera_world), errors=err)
