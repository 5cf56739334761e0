"""The head camera the landmark tests look through, and the poses of landmarks facing it: a
640 x 480 camera with a 600 px focal length and barrel distortion (HEAD_K, HEAD_DIST,
HEAD_CAMERA), and a mark turned obliquely to it (`mark_pose`)."""

from __future__ import annotations

import numpy as np

from core.geometry.rotations import rotvec_to_matrix
from core.sim.render.landmarks import LandmarkCamera

HEAD_K = [[600.0, 0.0, 321.5], [0.0, 600.0, 242.0], [0.0, 0.0, 1.0]]
HEAD_DIST = [-0.12, 0.05, 0.001, -0.0005, 0.0]
HEAD_CAMERA = LandmarkCamera(np.array(HEAD_K), np.array(HEAD_DIST), 640, 480)


def mark_pose(
    axis_deg: float, obliquity_deg: float, t: list[float], psi: float = 0.3
) -> np.ndarray:
    """Return T_cam_mark: the mark facing the camera, turned by `obliquity_deg` about an in-plane
    axis at `axis_deg` from the image x axis, and by psi about its normal."""
    a = np.radians(axis_deg)
    T = np.eye(4)
    T[:3, :3] = (
        rotvec_to_matrix(np.radians(obliquity_deg) * np.array([np.cos(a), np.sin(a), 0]))
        @ rotvec_to_matrix([np.pi, 0, 0])
        @ rotvec_to_matrix([0, 0, psi])
    )
    T[:3, 3] = t
    return T
