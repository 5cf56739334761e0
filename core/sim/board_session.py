"""Each ceiling camera's own calibration in the twin, from a chessboard the installer shows it.

A printed chessboard (`HANDHELD_BOARD`) is held up in front of each ceiling camera in a series
of poses, each frame is rendered, the board's corners are found against the empty room
(core.calibration.find_chessboard_on_background) and each camera gets its own Zhang calibration
(intrinsics, distortion, their covariance): `show_chessboard`, the first step of the marker
calibration drive (core.sim.network_drive). The installer places the board by looking at the
live image (the twin places it with the camera's pose, as a person watching the picture
would); only the detected corners reach the calibration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from core.calibration.detect import (
    Chessboard,
    board_object_points,
    find_chessboard_on_background,
)
from core.calibration.network import IntrinsicsPrior
from core.calibration.zhang import CameraCalibration, calibrate_camera
from core.errors import (
    ConvergenceError,
    DegenerateConfiguration,
    InvalidInput,
    NotEnoughPoints,
    PatternNotFound,
)
from core.geometry.camera import project_points, undistort_points
from core.geometry.rotations import rotvec_to_matrix
from core.sim.motion import WorldState, world_state
from core.sim.render import CameraModel, Renderer, SensorNoise
from core.sim.scene import Board

Array = NDArray[np.float64]

_DEFAULT_NOISE = SensorNoise()

#: The installer's printed board: 9 x 6 inner corners of 4 cm (a 40 cm x 28 cm print).
HANDHELD_BOARD = Board(inner_corners=(9, 6), square_size=0.04, margin=1.0)


@dataclass(frozen=True)
class BoardSession:
    """Each camera's own calibration from a shown chessboard: `calibrations` by camera name
    (Zhang, with covariance), `views` used per camera, `corner_sigma_px` the detected corners'
    RMS error per axis against the rendered truth (scoring only)."""

    calibrations: dict[str, CameraCalibration]
    views: dict[str, int]
    corner_sigma_px: float

    def priors(self, names: list[str]) -> list[IntrinsicsPrior]:
        """Return the intrinsics priors of the cameras `names`, in that order."""
        return [IntrinsicsPrior.from_calibration(self.calibrations[n]) for n in names]


def _board_pose(cam: CameraModel, pixel: Array, depth: float, tilt: Array, board: Board) -> Array:
    """Return T_world_board (4, 4) of a board centred on the ray of `pixel` at `depth` metres,
    facing the camera, turned by the rotation vector `tilt` (camera frame)."""
    ray = undistort_points(pixel, cam.K, cam.dist)
    centre = depth * np.array([ray[0], ray[1], 1.0])
    R_cb = rotvec_to_matrix(tilt)  # board axes in the camera frame; z away from the camera
    cols, rows = board.inner_corners
    half = np.array([(cols - 1) * board.square_size / 2, (rows - 1) * board.square_size / 2, 0.0])
    T_cb = np.eye(4)
    T_cb[:3, :3] = R_cb
    T_cb[:3, 3] = centre - R_cb @ half
    return cam.T_world_camera @ T_cb


def show_chessboard(
    renderer: Renderer,
    rng: np.random.Generator,
    *,
    views: int = 16,
    board: Board = HANDHELD_BOARD,
    noise: SensorNoise | None = _DEFAULT_NOISE,
    distortion: str = "k1k2p1p2k3",
) -> BoardSession:
    """Return each scene camera's own calibration from `views` frames of a shown chessboard.

    Poses: the board's centre on a ray through a cell of a 4 x 4 grid over the middle 76 % of
    the image (so the board reaches the image's edges and corners, where the distortion is
    strongest), 0.4 to 0.7 m from the camera, tilted 10 to 35 degrees about a random axis in
    the image plane and turned up to 20 degrees about its normal; a frame in which the board is
    not found is shown again at a new pose (up to three times). Raises InvalidInput when a
    camera ends with fewer than 4 views or its calibration fails (the message names it).
    """
    scene = renderer.scene
    people = world_state(scene, 0.0).people
    empty = WorldState(0.0, None, people)
    obj = board_object_points(Chessboard(*board.inner_corners), board.square_size)
    cals: dict[str, CameraCalibration] = {}
    used: dict[str, int] = {}
    errs: list[Array] = []
    for spec in scene.cameras:
        cam = renderer.camera(spec.name)
        background = renderer.render(cam.name, empty, rng=rng, noise=noise).image
        found: list[Array] = []
        for i in range(views):
            gx, gy = i % 4, (i // 4) % 4
            for _ in range(3):
                cell = 0.12 + 0.76 * (np.array([gx, gy]) + rng.uniform(0.2, 0.8, 2)) / 4
                pixel = cell * np.array([cam.width - 1, cam.height - 1])
                axis = rng.standard_normal(2)
                axis /= np.linalg.norm(axis)
                ang = math.radians(rng.uniform(10, 35))
                tilt = np.array([axis[0] * ang, axis[1] * ang, math.radians(rng.uniform(-20, 20))])
                T = _board_pose(cam, pixel, rng.uniform(0.4, 0.7), tilt, board)
                frame = renderer.render_board(
                    cam.name, board, T, rng=rng, noise=noise, people=people
                )
                try:
                    det = find_chessboard_on_background(
                        frame.image, background, board.inner_corners, scale=1.0
                    )
                except PatternNotFound:
                    continue
                found.append(det.corners)
                assert frame.board_corner_pixels is not None
                errs.append(det.corners - frame.board_corner_pixels)
                break
        if len(found) < 4:
            raise InvalidInput(
                f"camera {cam.name!r}: the shown board was found in only {len(found)} frames; "
                "needs at least 4 (check the camera's view and the board size)"
            )
        objs = [obj] * len(found)
        try:
            for _ in range(4):
                cal = _calibrate_robustly(objs, found, (cam.width, cam.height), distortion)
                # A view whose corners fit far worse than the others' (a corner caught on an
                # occluding edge) is dropped and the camera calibrated again.
                bad = cal.per_view_rms > max(3.0 * float(np.median(cal.per_view_rms)), 0.3)
                if bad.any() and len(found) - int(bad.sum()) >= 4:
                    objs = [o for o, b in zip(objs, bad, strict=True) if not b]
                    found = [c for c, b in zip(found, bad, strict=True) if not b]
                    continue
                # So is a single corner that fits far worse than the rest: one corner 2 px off
                # among 24 leaves its view's RMS unremarkable but moved a camera's principal
                # point by 2 px (9 of its standard deviations) on one drive.
                keep = _consistent_corners(cal, objs, found)
                if all(k.all() for k in keep):
                    break
                objs = [o[k] for o, k in zip(objs, keep, strict=True)]
                found = [c[k] for c, k in zip(found, keep, strict=True)]
        except (DegenerateConfiguration, NotEnoughPoints, ConvergenceError) as exc:
            raise InvalidInput(
                f"camera {cam.name!r}: its board calibration failed: {exc}"
            ) from None
        cals[cam.name] = cal
        used[cam.name] = len(found)
    e = np.concatenate(errs) if errs else np.zeros((0, 2))
    sigma = float(np.sqrt(np.mean(e**2))) if len(e) else float("nan")
    return BoardSession(cals, used, sigma)


def _calibrate_robustly(
    objs: list[Array], found: list[Array], size: tuple[int, int], distortion: str
) -> CameraCalibration:
    """Return the Zhang calibration of the views; when the closed form fails (close views
    fill the image, and the strong lens distortion it ignores leaves B indefinite), start from
    a nominal K instead (f = half the image width, principal point at the centre)."""
    try:
        return calibrate_camera(objs, found, size, distortion=distortion)
    except DegenerateConfiguration:
        w, h = size
        K0 = np.array([[0.5 * w, 0.0, 0.5 * (w - 1)], [0.0, 0.5 * w, 0.5 * (h - 1)], [0, 0, 1.0]])
        return calibrate_camera(objs, found, size, distortion=distortion, initial_K=K0)


# A corner whose reprojection error exceeds this many robust standard deviations of all the
# camera's corners (and CORNER_FLOOR_PX) is an outlier.
CORNER_OUTLIER_SIGMAS = 6.0
CORNER_FLOOR_PX = 0.3


def _consistent_corners(
    cal: CameraCalibration, objs: list[Array], found: list[Array]
) -> list[NDArray[np.bool_]]:
    """Return, per view, which corners fit the calibration within CORNER_OUTLIER_SIGMAS robust
    standard deviations (1.4826 MAD of every corner's error, per axis) or CORNER_FLOOR_PX; a
    view keeps all its corners when dropping some would leave it fewer than 8."""
    res = [
        project_points(o, p.rvec, p.t, cal.K, cal.dist).points - c
        for o, p, c in zip(objs, cal.poses, found, strict=True)
    ]
    flat = np.concatenate(res)
    sigma = 1.4826 * float(np.median(np.abs(flat - np.median(flat, axis=0))))
    limit = max(CORNER_OUTLIER_SIGMAS * sigma, CORNER_FLOOR_PX)
    keep = [np.linalg.norm(r, axis=1) <= limit for r in res]
    return [k if k.sum() >= 8 else np.ones_like(k) for k in keep]
