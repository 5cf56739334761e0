"""Network calibration scenarios of the twin: every ceiling camera calibrated by the robot.

* `network_calibration` (`network-calibration`): each camera shown a chessboard for its own
  intrinsics, the robot driving its marker through a programme of stops, the marker detected
  in the rendered images and the network calibrated jointly with the odometry as prior
  (core.sim.network_drive, core.calibration.network marker kind), then registered to the world
  by a tour of the signposts (core.sim.network_registration); errors against the twin's
  cameras beside the calibration's Cramer-Rao bound, and optionally an accuracy study over
  drive length and pixel noise (`accuracy_study`).
* `network_calibration_board` (`network-calibration-board`): the robot carries its chessboard;
  the corners are detected in the images, each camera gets a full Zhang calibration chained
  into the world by the robot's poses (board kind).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from core.calibration.detect import (
    Chessboard,
    board_object_points,
    find_chessboard_on_background,
)
from core.calibration.network import (
    CalibratedCamera,
    calibrate_network_board,
    calibrate_network_marker,
    registered,
)
from core.errors import InvalidInput, PatternNotFound
from core.geometry.camera import distort_normalized, undistort_points
from core.sim._floor import free_floor_grid, inside
from core.sim.board_session import BoardSession, show_chessboard
from core.sim.marker_observations import robot_markers
from core.sim.motion import Pose2D, WorldState, world_state
from core.sim.network_drive import (
    MarkerDrive,
    bound_for,
    drive_and_observe,
    drive_marker_calibration,
)
from core.sim.network_errors import aligned_errors, calibration_errors
from core.sim.network_registration import (
    SignpostRegistration,
    can_register,
    register_network,
)
from core.sim.render import CameraModel, Renderer, SensorNoise
from core.sim.scenarios.records import (
    AccuracyRow,
    CameraCalibrationError,
    NetworkCalibrationResult,
    RejectedCameraReport,
)
from core.sim.scene import Board, Scene, default_scene, raise_mast

Array = NDArray[np.float64]

_DEFAULT_NOISE = SensorNoise()

# The calibration drive's default length (s): spec 02's "a drive of at most 5 minutes".
DRIVE_S = 300.0
# The longest drive a caller may ask for (s): the programme's size follows the length asked.
MAX_DRIVE_S = 1800.0

INTRINSICS_FROM_BOARD = (
    "each camera's own Zhang calibration (k1k2p1p2k3) from a chessboard shown to it, "
    "with its covariance as the prior"
)


# --------------------------------------------------------------------------------------------
# Marker kind


def _camera_error(cal: CalibratedCamera, true: CameraModel) -> CameraCalibrationError:
    """Return the errors every calibration kind reports for one camera against the twin's
    (focal, position, rotation, poses seen, reprojection RMS); each kind adds its own fields
    (scoring)."""
    err = calibration_errors(cal, true)
    return CameraCalibrationError(
        name=cal.name,
        focal_error_pct=err.focal_pct,
        position_error_m=err.position_m,
        rotation_error_deg=err.rotation_deg,
        poses_seen=cal.poses_seen,
        rms_px=cal.rms,
    )


def camera_errors(
    calibration: Any,
    cameras: Sequence[CameraModel],
    bound: Sequence[Any] = (),
    start_frame: Any = None,
) -> tuple[CameraCalibrationError, ...]:
    """Return each calibrated camera's errors against the twin's `cameras`, the errors of
    the network's own geometry (`aligned_errors`), where given its bound and, for a network
    registered to the world, the errors of `start_frame` (the same calibration before the
    registration) (scoring)."""
    cals = list(calibration.cameras)
    trues = [next(cm for cm in cameras if cm.name == c.name) for c in cals]
    aligned = aligned_errors(cals, trues)
    b_of = {b.name: b for b in bound}
    before = {} if start_frame is None else {c.name: c for c in start_frame.cameras}
    out = []
    for cal, true, (ap, ar) in zip(cals, trues, aligned, strict=True):
        b = b_of.get(cal.name)
        s = calibration_errors(before[cal.name], true) if cal.name in before else None
        out.append(
            replace(
                _camera_error(cal, true),
                aligned_position_error_m=ap,
                aligned_rotation_error_deg=ar,
                bound_focal_pct=None if b is None else b.focal_pct,
                bound_position_m=None if b is None else b.position_m,
                bound_rotation_deg=None if b is None else b.rotation_deg,
                bound_aligned_position_m=None if b is None else b.aligned_position_m,
                bound_aligned_rotation_deg=None if b is None else b.aligned_rotation_deg,
                start_frame_position_error_m=None if s is None else s.position_m,
                start_frame_rotation_error_deg=None if s is None else s.rotation_deg,
            )
        )
    return tuple(out)


def accuracy_study(
    scene: Scene | None = None,
    seeds: Sequence[int] = (0,),
    *,
    budgets: Sequence[float] = (100.0, 200.0, 300.0),
    sigmas: Sequence[float] = (0.25, 0.5, 1.0),
    revisit_below: int = 20,
    session: BoardSession | None = None,
    renderer: Renderer | None = None,
) -> tuple[AccuracyRow, ...]:
    """Return the calibration's errors and Cramer-Rao bounds as functions of the drive length
    and the pixel noise: for each seed, each camera's own chessboard calibration (rendered
    images; or `session` for every seed), then for each of `budgets` (seconds) a drive of at
    most that long (planned stops, then the second pass for cameras below `revisit_below`
    stops) and for each of `sigmas` the marker's true projections plus Gaussian noise of that
    many pixels, calibrated and scored. About 5 s per drive and noise on the default home."""
    scene = raise_mast(scene or default_scene())
    if scene.robot is None or scene.robot.marker is None:
        raise InvalidInput("the accuracy study needs a scene whose robot carries a marker")
    renderer = renderer.for_scene(scene) if renderer is not None else Renderer(scene)
    robot = scene.robot
    heights, offsets, _ = robot_markers(robot)
    cams = [renderer.camera(c.name) for c in scene.cameras]
    names = [c.name for c in cams]
    rows = []
    for seed in seeds:
        rng = np.random.default_rng([seed, 7])
        ses = session or show_chessboard(renderer, rng)
        for budget in budgets:
            # About 9 s per planned stop (driving, braking, the dwell); the second pass fills
            # what the budget leaves.
            m = max(6, round(budget / 9.0))
            for sigma in sigmas:
                # The same drive for every noise level (same generator): the noise draws scale.
                drive, obs = drive_and_observe(
                    renderer,
                    np.random.default_rng([seed, round(budget)]),
                    m,
                    mode="projections",
                    sigma_px=sigma,
                    revisit_below=revisit_below,
                    max_drive_s=budget,
                )
                pixels, cov, seen, _ = obs.stacked()
                net = calibrate_network_marker(
                    names,
                    ses.priors(names),
                    pixels,
                    seen,
                    drive.odometry,
                    heights,
                    offset=offsets,
                    pixel_cov=cov,
                )
                done = [c.name for c in net.cameras]
                bound = bound_for(done, ses, cams, drive, obs, robot)
                rows.append(
                    AccuracyRow(
                        seed=seed,
                        stops=m,
                        poses=len(drive.true_poses),
                        drive_s=drive.duration_s,
                        sigma_px=float(sigma),
                        cameras=camera_errors(net, cams, bound),
                        rejected=tuple(r.name for r in net.rejected),
                    )
                )
    return tuple(rows)


def drive_programme(
    minutes: float, stops: int = 32, revisit_below: int = 20
) -> tuple[float, int, int]:
    """Return the calibration drive of at most `minutes` as (its length in seconds, its
    planned stops, the second pass's floor): `stops` and `revisit_below` are per 5 minutes of
    drive and scale with its length. Raises InvalidInput for a length that is not a number
    of more than 0 and at most MAX_DRIVE_S / 60 minutes (checked before anything is planned:
    the programme's size follows the length asked)."""
    if not (math.isfinite(minutes) and 0 < minutes <= MAX_DRIVE_S / 60.0):
        raise InvalidInput(
            f"minutes must be a drive of more than 0 and at most {MAX_DRIVE_S / 60.0:g} "
            f"minutes, got {minutes}"
        )
    budget = 60.0 * minutes
    return (
        budget,
        max(4, round(stops * budget / DRIVE_S)),
        round(revisit_below * budget / DRIVE_S),
    )


def network_calibration(
    scene: Scene | None = None,
    seed: int = 0,
    *,
    stops: int = 32,
    revisit_below: int = 20,
    mode: str = "images",
    sigma_px: float = 0.5,
    noise: SensorNoise | None = _DEFAULT_NOISE,
    min_poses: int = 6,
    camera_poses: dict[str, int] | None = None,
    study: bool = False,
    target: str = "marker",
    register: bool = True,
    minutes: float | None = None,
) -> NetworkCalibrationResult:
    """Return the metrics of calibrating the scene's cameras by driving the robot's marker
    (`target` "marker") or its chessboard (`target` "board": `network_calibration_board`).

    Marker: core.sim.network_drive.drive_marker_calibration with `stops` planned stops and a
    second pass for cameras below `revisit_below`; the marker detected in rendered images
    (`mode` "images") or its true projections plus `sigma_px` of Gaussian noise
    ("projections"). `camera_poses` optionally caps how many stops a named camera gets to see
    (robustness checks). With `study` the record carries `accuracy_study` for this seed
    (drives of at most 100, 200 and 300 s; noise 0.25, 0.5, 1 px), reusing the cameras' own
    calibration. With `register` (and a home with signposts and a robot with a head camera)
    the robot then tours the signposts and the network is registered to the world
    (core.sim.network_registration); the errors are then the registered network's, with those
    of the start pose's frame beside them. Errors and bounds are against the scene.
    `minutes` sets the drive's length instead (at most that long, 5 minutes by default): the
    planned stops and the second pass's floor scale with it (32 and 20 per 5 minutes).
    """
    if target == "board":
        return network_calibration_board(
            scene, seed, noise=noise, min_views=max(min_poses, 8), camera_views=camera_poses
        )
    if target != "marker":
        raise InvalidInput(f"unknown calibration target {target!r}; use 'marker' or 'board'")
    scene = raise_mast(scene or default_scene())
    renderer = Renderer(scene)
    budget = DRIVE_S
    if minutes is not None:
        budget, stops, revisit_below = drive_programme(minutes, stops, revisit_below)
    md = drive_marker_calibration(
        scene,
        seed,
        stops=stops,
        revisit_below=revisit_below,
        mode=mode,
        sigma_px=sigma_px,
        noise=noise,
        min_poses=min_poses,
        camera_poses=camera_poses,
        renderer=renderer,
        max_drive_s=budget,
    )
    accuracy: tuple[AccuracyRow, ...] = ()
    if study:
        accuracy = accuracy_study(scene, (seed,), session=md.intrinsics, renderer=renderer)
    tour = None
    if register and can_register(scene):
        _, tour = register_network(md.calibration, scene, seed, renderer=renderer)
    return marker_result(md, seed, accuracy, tour)


def marker_result(
    md: MarkerDrive,
    seed: int,
    accuracy: tuple[AccuracyRow, ...] = (),
    tour: SignpostRegistration | None = None,
) -> NetworkCalibrationResult:
    """Return the scenario record of a marker calibration drive, registered to the world by
    the signpost `tour` when it gave a registration."""
    net = md.calibration
    start_frame = None
    registration = None
    if tour is not None and tour.registration is not None:
        reg = tour.registration
        start_frame, net = net, registered(net, reg)
        registration = {
            "signposts_declared": tour.declared,
            "signposts_read": tour.read,
            "sightings": len(tour.sightings),
            "theta_deg": float(np.degrees(reg.theta)),
            "theta_std_deg": reg.theta_std_deg,
            "t_m": [float(v) for v in reg.t],
            "t_std_m": [float(np.sqrt(reg.cov[1, 1])), float(np.sqrt(reg.cov[2, 2]))],
            "residual_rms_m": float(np.sqrt(np.mean(np.sum(reg.residuals**2, axis=1)))),
            "tour_s": tour.duration_s,
        }
    return NetworkCalibrationResult(
        scenario="network-calibration",
        seed=seed,
        target_kind="marker",
        poses=md.poses,
        detections=int(md.seen.sum()),
        drive_s=md.drive.duration_s,
        sigma_px=md.observations.sigma_px,
        intrinsics_from=INTRINSICS_FROM_BOARD,
        distortion="from each camera's own calibration, refined jointly within its covariance",
        rms_px=net.rms_px,
        rms_whitened=net.rms_whitened,
        cameras=camera_errors(net, md.true_cameras, md.bound, start_frame),
        rejected=tuple(RejectedCameraReport(r.name, r.reason, r.poses_seen) for r in net.rejected),
        accuracy=accuracy,
        registration=registration,
        registration_reason="" if tour is None else tour.reason,
    )


# --------------------------------------------------------------------------------------------
# Board kind


def mount_board(scene: Scene) -> Scene:
    """Return the scene with its robot's chessboard mounted (enabled), in the place of the
    mast, which it would otherwise cut through. InvalidInput without a board."""
    if scene.robot is None or scene.robot.board is None:
        raise InvalidInput("the scene's robot carries no chessboard to mount")
    board = scene.robot.board.model_copy(update={"enabled": True})
    robot = scene.robot.model_copy(
        update={"board": board, "mast_marker": None, "calibration_mast": None}
    )
    return scene.model_copy(update={"robot": robot})


def board_mounting(board: Board) -> tuple[Array, Array]:
    """Return the board's model points (N, 3) in its own frame (metres, Z = 0, row by row as
    core.calibration.board_object_points) and its mounting T_robot_board (4, 4).

    The board frame has its origin at the first inner corner, x along the board's columns
    (robot +y), y down its rows (forward and down the tilt), z = x cross y (into the board,
    away from its printed face); the grid is centred on (offset, mounting_height) of the robot
    frame, as the renderer draws it (core.sim.scene.Board).
    """
    cols, rows = board.inner_corners
    s = board.square_size
    t = board.tilt
    u = np.array([0.0, 1.0, 0.0])
    v = np.array([math.cos(t), 0.0, -math.sin(t)])
    centre = np.array([board.offset[0], board.offset[1], board.mounting_height])
    T = np.eye(4)
    T[:3, :3] = np.column_stack([u, v, np.cross(u, v)])
    T[:3, 3] = centre - u * (cols - 1) * s / 2 - v * (rows - 1) * s / 2
    return board_object_points(Chessboard(cols, rows), s), T


def _distortion_error_px(est_dist: Array, true: CameraModel, region: Array | None = None) -> float:
    """Return the largest difference (pixels of the true focal length) between the estimated and
    the true distortion displacement, over the rays that land in the true image, or only those
    inside the convex hull of `region` (K, 2) pixels when given."""
    u, v = np.meshgrid(np.linspace(0, true.width - 1, 65), np.linspace(0, true.height - 1, 49))
    px = np.stack([u.ravel(), v.ravel()], 1)
    if region is not None:
        hull = cv2.convexHull(region.astype(np.float32)).reshape(-1, 2).astype(np.float64)
        px = px[inside(px, hull)]
    x = undistort_points(px, true.K, true.dist)
    d_true = distort_normalized(x, true.dist) - x
    d_est = distort_normalized(x, est_dist) - x
    f = 0.5 * (true.K[0, 0] + true.K[1, 1])
    return float(np.max(f * np.linalg.norm(d_est - d_true, axis=1)))


def network_calibration_board(
    scene: Scene | None = None,
    seed: int = 0,
    *,
    spacing: float = 0.3,
    placement_sigma: float = 0.002,
    yaw_sigma: float = 0.003,
    noise: SensorNoise | None = _DEFAULT_NOISE,
    min_views: int = 8,
    camera_views: dict[str, int] | None = None,
    refine_poses: bool = True,
    distortion: str = "k1k2p1p2",
    revisit_below: int = 50,
) -> NetworkCalibrationResult:
    """Return the metrics of calibrating the scene's cameras by driving the robot's chessboard.

    The scene's robot board is mounted (`mount_board`) if the scene carries it unmounted.
    Programme:
    as `network_calibration` (a grid of stops `spacing` metres apart, random yaw), the robot
    stopping within `placement_sigma` metres per axis and `yaw_sigma` radians of each scripted
    pose, which is what the calibration is told, with those standard deviations as its prior.
    Every camera that could hold the whole board renders every stop; the board's corners are
    found in the image by core.calibration.find_chessboard_on_background against an empty-room
    frame of the same camera (no
    ground truth is used). A camera left with fewer than `revisit_below` views gets a second
    pass: the robot returns, with new headings, to the stops where that camera found the board.
    Each camera is Zhang-calibrated with `distortion` and chained into the world
    (core.calibration.network.calibrate_network_board). `camera_views` optionally caps how many
    board views a named camera keeps. Errors are against the scene. About 20 s of CPU on the
    default home (about 290 stops).
    """
    scene = scene or default_scene()
    if scene.robot is None or scene.robot.board is None:
        raise InvalidInput("network-calibration-board needs a scene whose robot carries a board")
    if not scene.cameras:
        raise InvalidInput("network-calibration needs a scene with cameras")
    scene = mount_board(scene)
    assert scene.robot is not None and scene.robot.board is not None
    board = scene.robot.board
    rng = np.random.default_rng(seed)
    renderer = Renderer(scene)
    points, T_rb = board_mounting(board)
    cams = [renderer.camera(cs.name) for cs in scene.cameras]
    people = world_state(scene, 0.0).people
    empty = WorldState(0.0, None, people)
    backgrounds = [renderer.render(cm.name, empty, rng=rng, noise=noise).image for cm in cams]
    errs: list[Array] = []

    def drive(stops: Array) -> tuple[Array, Array, NDArray[np.bool_]]:
        """Stop at scripted (x, y) stops (S, 2) with random yaw; return the scripted poses
        (S, 3), the corners found (C, S, N, 2) and which cameras found them (C, S)."""
        yaw = rng.uniform(-math.pi, math.pi, len(stops))
        xy = stops + placement_sigma * rng.standard_normal(stops.shape)
        yaw_true = yaw + yaw_sigma * rng.standard_normal(len(stops))
        found = np.zeros((len(cams), len(stops), len(points), 2))
        ok = np.zeros((len(cams), len(stops)), bool)
        # Only to save rendering time: a camera is not rendered when the board's centre is
        # behind it or projects far outside its image (no whole board could be found there).
        centre = np.column_stack([xy, np.full(len(xy), T_rb[2, 3])])
        for j in range(len(stops)):
            state = WorldState(0.0, Pose2D(float(xy[j, 0]), float(xy[j, 1]), yaw_true[j]), people)
            for k, cam in enumerate(cams):
                u, v = cam.project(centre[j])[0]
                if cam.depth(centre[j])[0] <= 0.3 or not (
                    -0.2 * cam.width < u < 1.2 * cam.width
                    and -0.2 * cam.height < v < 1.2 * cam.height
                ):
                    continue
                frame = renderer.render(cam.name, state, rng=rng, noise=noise)
                try:
                    det = find_chessboard_on_background(
                        frame.image, backgrounds[k], board.inner_corners
                    )
                except PatternNotFound:
                    continue
                found[k, j], ok[k, j] = det.corners, True
                if frame.board_corner_pixels is not None:
                    errs.append(det.corners - frame.board_corner_pixels)
        return np.column_stack([stops, yaw]), found, ok

    grid = free_floor_grid(scene, spacing, scene.robot.base_radius + 0.05)
    grid = grid + rng.uniform(-0.1, 0.1, grid.shape) * spacing
    poses, corners, seen = drive(grid)
    # Second pass: the robot goes back, with new headings, to where a camera that saw the
    # board fewer than `revisit_below` times saw it (known from its detections alone).
    short = seen.sum(1) < revisit_below
    if np.any(short):
        again = poses[np.any(seen[short], axis=0), :2]
        again = again + rng.uniform(-0.1, 0.1, again.shape) * spacing
        p2, c2, s2 = drive(again)
        poses = np.vstack([poses, p2])
        corners = np.concatenate([corners, c2], axis=1)
        seen = np.concatenate([seen, s2], axis=1)
    M = len(poses)
    for name, cap in (camera_views or {}).items():
        k = [cm.name for cm in cams].index(name)
        seen[k, np.flatnonzero(seen[k])[cap:]] = False
    net = calibrate_network_board(
        [cm.name for cm in cams],
        [(cm.width, cm.height) for cm in cams],
        corners,
        seen,
        points,
        T_rb,
        poses,
        distortion=distortion,
        pose_sigma=(placement_sigma, yaw_sigma) if refine_poses else (0.0, 0.0),
        min_views=min_views,
    )
    errors = []
    k_of = {cm.name: k for k, cm in enumerate(cams)}
    for cal in net.cameras:
        true = next(cm for cm in cams if cm.name == cal.name)
        errors.append(
            replace(
                _camera_error(cal, true),
                principal_point_error_px=float(np.linalg.norm(cal.K[:2, 2] - true.K[:2, 2])),
                distortion_error_px=_distortion_error_px(
                    cal.dist, true, corners[k_of[cal.name]][seen[k_of[cal.name]]].reshape(-1, 2)
                ),
                distortion_error_full_px=_distortion_error_px(cal.dist, true),
            )
        )
    return NetworkCalibrationResult(
        scenario="network-calibration-board",
        seed=seed,
        target_kind="board",
        poses=M,
        detections=int(seen.sum()),
        drive_s=None,
        sigma_px=float(np.sqrt(np.mean(np.concatenate(errs) ** 2))) if errs else float("nan"),
        intrinsics_from=f"each camera's Zhang calibration ({distortion}) from the robot's board",
        distortion=f"estimated per camera (Zhang, {distortion})",
        rms_px=net.rms_px,
        rms_whitened=net.rms_whitened,
        placement_sigma_m=placement_sigma,
        cameras=tuple(errors),
        rejected=tuple(RejectedCameraReport(r.name, r.reason, r.poses_seen) for r in net.rejected),
    )
