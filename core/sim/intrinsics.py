"""A twin camera's intrinsics as its owner would get them: Zhang from rendered chessboard views.

Every estimator of the twin that needs a camera's K and distortion (the head camera's landmark
detector, the floor camera's spot back-projection, the eye-in-hand camera's pose estimates)
takes them from this calibration, never from the twin's true lens: the true lens only forms the
images (core.sim.render.landmarks) and scores the result.

A printed 9 x 6 (inner corners) chessboard of 25 mm squares is held in front of the camera at
0.35-0.6 m, tilted 10-40 deg about varied axes and turned a little, and rendered through the
true lens with the given sensor noise; core.calibration.find_chessboard detects its corners and
core.calibration.calibrate_camera (Zhang 2000, OpenCV's k1 k2 p1 p2 model) fits K and dist.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from core.calibration import calibrate_camera, find_chessboard
from core.calibration.detect import Chessboard, board_object_points
from core.errors import IntspaceError, InvalidInput
from core.geometry.rotations import rotvec_to_matrix
from core.sim.render import SensorNoise
from core.sim.render.landmarks import LandmarkCamera, Texture, render_landmarks

Array = NDArray[np.float64]

BOARD = Chessboard(9, 6)
SQUARE = 0.025  # m
VIEWS = 12
# The sensor noise of the head camera's views (spec 07's head camera, landmark scenarios).
NOISE = SensorNoise(sigma=2.0, blur_sigma=0.5, gain=1.0, gain_jitter=0.05)


@dataclass(frozen=True, eq=False)
class RenderedCalibration:
    """A camera's calibrated intrinsics: K (3, 3), dist (5,) OpenCV order, the calibration's RMS
    reprojection error (px) and the number of views whose board was found (`views`)."""

    K: Array
    dist: Array
    rms: float
    views: int

    @property
    def source(self) -> str:
        """Where the intrinsics come from, as the scenarios' records state it."""
        return f"Zhang calibration from {self.views} rendered chessboard views"


def _board_texture() -> Texture:
    px = 40
    cols, rows = BOARD.cols + 1, BOARD.rows + 1
    img = np.full(((rows + 2) * px, (cols + 2) * px), 255, np.uint8)
    for r in range(rows):
        for c in range(cols):
            if (r + c) % 2 == 0:
                img[(r + 1) * px : (r + 2) * px, (c + 1) * px : (c + 2) * px] = 0
    bgr = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    ppm = px / SQUARE
    return Texture(bgr, ppm, (img.shape[1] / 2 / ppm, img.shape[0] / 2 / ppm))


def facing(obliquity: float, axis_angle: float, psi: float) -> Array:
    """Return R_cam_mark (3, 3) of a plane facing the camera, tilted by `obliquity` (rad) about
    the in-image axis at `axis_angle` (rad) and turned by `psi` (rad) about its normal."""
    a = np.array([np.cos(axis_angle), np.sin(axis_angle), 0.0])
    return (
        rotvec_to_matrix(obliquity * a)
        @ rotvec_to_matrix([np.pi, 0, 0])
        @ rotvec_to_matrix([0, 0, psi])
    )


def calibrate_from_board_views(
    camera: LandmarkCamera,
    rng: np.random.Generator,
    views: int = VIEWS,
    noise: SensorNoise | None = NOISE,
) -> RenderedCalibration:
    """Return the intrinsics of `camera` calibrated from `views` rendered chessboard views
    (module docstring); views whose board is not found are drawn again (up to 6 x `views`
    draws). Raises InvalidInput when fewer than 3 boards were found."""
    if views < 3:
        raise InvalidInput(f"a calibration needs >= 3 views, got {views}")
    tex = _board_texture()
    obj_all = board_object_points(BOARD, SQUARE)
    centre = obj_all[:, :2].mean(0)
    objs: list[Array] = []
    imgs: list[Array] = []
    tries = 0
    while len(objs) < views and tries < 6 * views:
        tries += 1
        T = np.eye(4)
        # Tilts up to 40 deg about varied axes, 0.35-0.6 m: the board fills much of the image.
        T[:3, :3] = facing(
            np.radians(rng.uniform(10, 40)), rng.uniform(0, 2 * np.pi), rng.uniform(-0.3, 0.3)
        )
        T[:3, 3] = [rng.uniform(-0.05, 0.05), rng.uniform(-0.04, 0.04), rng.uniform(0.35, 0.6)]
        view = render_landmarks(camera, [(tex, T)], noise=noise, rng=rng)
        try:
            # The board fills much of every view: SB without its exhaustive search finds it
            # with the same corners in a third of the time (core.calibration.find_chessboard).
            det = find_chessboard(view.image, (BOARD.cols, BOARD.rows), thorough=False)
        except IntspaceError:
            continue
        objs.append(det.object_points(SQUARE) - [centre[0], centre[1], 0.0])
        imgs.append(det.corners)
    if len(objs) < 3:
        raise InvalidInput(f"only {len(objs)} of {tries} rendered chessboard views were found")
    cal = calibrate_camera(objs, imgs, (camera.width, camera.height), distortion="k1k2p1p2")
    return RenderedCalibration(cal.K, cal.dist, float(cal.rms), len(objs))


def focal_error_pct(K: Array, K_true: Array) -> float:
    """Return the mean focal length's relative error (%) of K against the true K (scoring)."""
    f = (K[0, 0] + K[1, 1]) / 2
    f_true = (K_true[0, 0] + K_true[1, 1]) / 2
    return float(100.0 * abs(f - f_true) / f_true)


__all__ = [
    "BOARD",
    "NOISE",
    "SQUARE",
    "VIEWS",
    "RenderedCalibration",
    "calibrate_from_board_views",
    "facing",
    "focal_error_pct",
]
