"""Named, seeded scenarios of the digital twin, each returning its metrics as a typed record.

* `network-calibration`: the robot's marker is driven over a programme of floor poses, every
  camera renders it, the marker is detected in the images and the network calibrated from
  the detections (core.calibration.network, marker kind); errors against the twin's cameras.
  With `target="board"` (also the named scenario `network-calibration-board`) the robot
  carries its chessboard instead: the corners are detected in the images, each camera gets a
  full Zhang calibration (intrinsics and distortion) chained into the world by the robot's
  poses (board kind).
* `localization`: floor points seen by >= 2 of the twin's true cameras, pixels = projections
  plus Gaussian noise; the RMSE of the four ground estimators against the Cramer-Rao bound.
* `localization-images`: the same estimators on the marker detected in rendered images, with
  the measured pixel noise of the detector beside the errors.

`run_scenario(name, scene=None, seed=0)` runs one; `SCENARIOS` lists them. Every record has
`to_dict()` giving plain JSON-ready values.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from core.calibration.detect import Chessboard, board_object_points, find_chessboard
from core.calibration.network import calibrate_network_board, calibrate_network_marker
from core.errors import InvalidInput, PatternNotFound
from core.geometry.camera import distort_normalized, undistort_points
from core.geometry.rotations import matrix_to_rotvec
from core.localization import (
    NetworkCamera,
    cramer_rao_bound,
    locate_ml,
    locate_monocular,
    triangulate_linear,
    triangulate_on_plane,
)
from core.localization.detect import MarkerDetectorConfig, detect_marker
from core.sim.motion import Pose2D, WorldState, world_state
from core.sim.render import CameraModel, Renderer, SensorNoise
from core.sim.scene import Board, Scene, default_scene

Array = NDArray[np.float64]

_DEFAULT_NOISE = SensorNoise()
# cornerSubPix half-window (px) on the original pixels: a quarter of the board's ~9 px squares.
_REFINE_WIN = 2
# Pixels of each of the board's black and white needed before it is searched for.
_MIN_INK = 20


# --------------------------------------------------------------------------------------------
# Records


@dataclass(frozen=True)
class CameraCalibrationError:
    """One camera's calibration against the twin: focal error in percent of the true
    (fx + fy) / 2 (signed, of the estimated (fx + fy) / 2), optical-centre position error
    metres, orientation error degrees (angle of R_est R_true^T), poses seen, reprojection RMS
    pixels. Board kind only (None otherwise): principal point error pixels (distance), and
    distortion error pixels: the largest difference between the estimated and the true lens
    distortion displacement, f_true |(D_est(x) - x) - (D_true(x) - x)| over ideal normalised
    rays x (the distortion alone, focal and principal point errors excluded), over the part of
    the image the board's detections covered (their convex hull; `distortion_error_px`) and
    over the whole image (`distortion_error_full_px`, extrapolated where the board never
    went: the image's upper part sees walls the robot cannot reach)."""

    name: str
    focal_error_pct: float
    position_error_m: float
    rotation_error_deg: float
    poses_seen: int
    rms_px: float
    principal_point_error_px: float | None = None
    distortion_error_px: float | None = None
    distortion_error_full_px: float | None = None


@dataclass(frozen=True)
class RejectedCameraReport:
    """A camera the calibration left out, with the reason."""

    name: str
    reason: str
    poses_seen: int


@dataclass(frozen=True)
class NetworkCalibrationResult:
    """Metrics of `network-calibration`: per-camera errors, rejected cameras, the number of
    programme poses and detections, the target kind used and how the targets were treated."""

    scenario: str
    seed: int
    target_kind: str
    poses: int
    detections: int
    placement_sigma_m: float
    distortion: str
    cameras: tuple[CameraCalibrationError, ...]
    rejected: tuple[RejectedCameraReport, ...]

    def to_dict(self) -> dict[str, Any]:
        """Return the record as JSON-ready values."""
        return asdict(self)


@dataclass(frozen=True)
class LocalizationResult:
    """Metrics of `localization` / `localization-images`: samples located, pixel noise sigma
    (given, or measured from the detections), RMSE metres per estimator (mono, linear,
    constrained, ml) and the Cramer-Rao root mean trace for the cameras ML used."""

    scenario: str
    seed: int
    samples: int
    sigma_px: float
    rmse_m: dict[str, float]
    crb_rmse_m: float
    measured_sigma_px: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """Return the record as JSON-ready values."""
        return asdict(self)


ScenarioResult = NetworkCalibrationResult | LocalizationResult


# --------------------------------------------------------------------------------------------
# Helpers


def _free_floor_grid(scene: Scene, spacing: float, clearance: float) -> Array:
    """Return floor points (N, 2) on a grid of `spacing` metres inside the rooms, at least
    `clearance` metres from every wall and furniture footprint (robot radius plus margin)."""
    rooms = np.array([p for r in scene.rooms for p in r.polygon])
    lo, hi = rooms.min(0), rooms.max(0)
    gx = np.arange(lo[0] + spacing / 2, hi[0], spacing)
    gy = np.arange(lo[1] + spacing / 2, hi[1], spacing)
    P = np.stack(np.meshgrid(gx, gy), -1).reshape(-1, 2)
    ok = np.zeros(len(P), bool)
    for room in scene.rooms:
        ok |= _inside(P, np.array(room.polygon))
    for w in scene.walls:
        a, b = np.array(w.start), np.array(w.end)
        d = b - a
        s = np.clip((P - a) @ d / (d @ d), 0, 1)
        ok &= np.linalg.norm(P - (a + s[:, None] * d), axis=1) > clearance + w.thickness / 2
    for f in scene.furniture:
        c, s_ = math.cos(f.yaw), math.sin(f.yaw)
        q = (P - np.array(f.centre)) @ np.array([[c, -s_], [s_, c]])
        half = np.array(f.size[:2]) / 2 + clearance
        ok &= ~np.all(np.abs(q) < half, axis=1)
    return P[ok]


def _inside(P: Array, poly: Array) -> NDArray[np.bool_]:
    """Return whether points (N, 2) lie inside a simple polygon (V, 2) (even-odd rule)."""
    x, y = P[:, 0:1], P[:, 1:2]
    a, b = poly, np.roll(poly, -1, axis=0)
    cross = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xi = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return np.asarray(np.sum(cross & (x < xi), axis=1) % 2 == 1)


def _rotation_angle_deg(Ra: Array, Rb: Array) -> float:
    return float(np.degrees(np.linalg.norm(matrix_to_rotvec(Ra @ Rb.T))))


def _true_network(renderer: Renderer) -> list[tuple[CameraModel, NetworkCamera]]:
    out = []
    for spec in renderer.scene.cameras:
        m = renderer.camera(spec.name)
        nc = NetworkCamera.from_pose(m.K, m.dist, m.T_world_camera, (m.width, m.height), m.name)
        out.append((m, nc))
    return out


@dataclass(frozen=True)
class MarkerDrive:
    """What a marker calibration drive produced: the network calibration, the scene's true
    cameras (for errors against the twin), the number of stops and which camera saw which stop
    (C, M)."""

    calibration: Any  # core.calibration.network.NetworkCalibration
    true_cameras: tuple[CameraModel, ...]
    poses: int
    seen: NDArray[np.bool_]


def drive_marker_calibration(
    scene: Scene,
    seed: int,
    *,
    spacing: float = 0.3,
    placement_sigma: float = 0.002,
    noise: SensorNoise | None = _DEFAULT_NOISE,
    min_poses: int = 8,
    camera_poses: dict[str, int] | None = None,
    refine_targets: bool = True,
    renderer: Renderer | None = None,
) -> MarkerDrive:
    """Return the network calibration from driving the robot's marker over the free floor.

    Programme: a grid of floor poses `spacing` metres apart (jittered, random yaw), stop and go;
    the robot stops within `placement_sigma` metres (per axis, Gaussian) of each scripted pose,
    which is what the calibration is told, with that standard deviation as its prior. Every
    camera renders every stop and the marker is detected in the image (no ground truth); the
    principal points and lens distortion are the scene's, as the marker kind requires.
    `camera_poses` optionally caps how many stops a named camera sees; `renderer` reuses one
    whose static layers are built. Raises InvalidInput for a scene without cameras or marker.
    """
    if scene.robot is None or scene.robot.marker is None:
        raise InvalidInput("network-calibration needs a scene whose robot carries a marker")
    if not scene.cameras:
        raise InvalidInput("network-calibration needs a scene with cameras")
    rng = np.random.default_rng(seed)
    renderer = renderer or Renderer(scene)
    marker = scene.robot.marker
    grid = _free_floor_grid(scene, spacing, scene.robot.base_radius + 0.05)
    grid = grid + rng.uniform(-0.1, 0.1, grid.shape) * spacing
    yaw = rng.uniform(-math.pi, math.pi, len(grid))
    truth = grid + placement_sigma * rng.standard_normal(grid.shape)
    # The marker's floor position for a robot pose (x, y, yaw): its offset turned by yaw.
    off = np.array(marker.offset)
    c, s = np.cos(yaw), np.sin(yaw)
    rot_off = np.stack([c * off[0] - s * off[1], s * off[0] + c * off[1]], 1)
    cams = [renderer.camera(cs.name) for cs in scene.cameras]
    C, M = len(cams), len(grid)
    pixels = np.zeros((C, M, 2))
    cov = np.tile(np.eye(2), (C, M, 1, 1))
    seen = np.zeros((C, M), bool)
    cfg = MarkerDetectorConfig(colour=marker.colour)
    for j in range(M):
        state = world_state(scene, 0.0, Pose2D(float(truth[j, 0]), float(truth[j, 1]), yaw[j]))
        for k, cam in enumerate(cams):
            frame = renderer.render(cam.name, state, rng=rng, noise=noise)
            det = detect_marker(frame.image, cfg)
            if det is not None:
                pixels[k, j], cov[k, j], seen[k, j] = det.pixel, det.cov, True
    for name, cap in (camera_poses or {}).items():
        k = [cm.name for cm in cams].index(name)
        idx = np.flatnonzero(seen[k])
        seen[k, idx[cap:]] = False
    net = calibrate_network_marker(
        [cm.name for cm in cams],
        [cm.K[:2, 2] for cm in cams],
        [cm.dist for cm in cams],
        pixels,
        seen,
        grid + rot_off,
        marker.height,
        pixel_cov=cov,
        target_sigma=placement_sigma if refine_targets else 0.0,
        min_poses=min_poses,
    )
    return MarkerDrive(net, tuple(cams), M, seen)


@dataclass(frozen=True)
class PoseErrors:
    """Errors of a calibrated camera against the twin's true camera: focal length (% of the
    true mean focal length), position (m) and orientation (degrees)."""

    focal_pct: float
    position_m: float
    rotation_deg: float


def calibration_errors(cal: Any, true: CameraModel) -> PoseErrors:
    """Return the errors of `cal` (a core.calibration.network.CalibratedCamera) against the
    scene's camera `true`."""
    f_true = 0.5 * (true.K[0, 0] + true.K[1, 1])
    return PoseErrors(
        focal_pct=float(100 * (cal.focal - f_true) / f_true),
        position_m=float(np.linalg.norm(cal.position - true.position)),
        rotation_deg=_rotation_angle_deg(cal.R, true.R_camera_world),
    )


# --------------------------------------------------------------------------------------------
# Scenarios


def network_calibration(
    scene: Scene | None = None,
    seed: int = 0,
    *,
    spacing: float = 0.3,
    placement_sigma: float = 0.002,
    noise: SensorNoise | None = _DEFAULT_NOISE,
    min_poses: int = 8,
    camera_poses: dict[str, int] | None = None,
    refine_targets: bool = True,
    target: str = "marker",
) -> NetworkCalibrationResult:
    """Return the metrics of calibrating the scene's cameras by driving the robot's marker
    (`target` "marker") or its chessboard (`target` "board": `network_calibration_board` with
    the same programme options, `min_poses` and `camera_poses` counting board views).

    Programme: a grid of floor poses `spacing` metres apart over the free floor (random yaw),
    stop-and-go; the robot stops within `placement_sigma` metres (per axis, Gaussian) of each
    scripted pose, and the scripted pose is what the calibration is told, with that standard
    deviation as its prior. Every camera renders every stop; the marker is detected (no ground
    truth); the principal points and the lens distortion are taken from the scene as the
    "given" and "known" values the marker kind requires. `camera_poses` optionally caps how many
    stops a named camera gets to see (for robustness checks). Errors are against the scene.
    """
    if target == "board":
        return network_calibration_board(
            scene,
            seed,
            spacing=spacing,
            placement_sigma=placement_sigma,
            noise=noise,
            min_views=min_poses,
            camera_views=camera_poses,
            refine_poses=refine_targets,
        )
    if target != "marker":
        raise InvalidInput(f"unknown calibration target {target!r}; use 'marker' or 'board'")
    drive = drive_marker_calibration(
        scene or default_scene(),
        seed,
        spacing=spacing,
        placement_sigma=placement_sigma,
        noise=noise,
        min_poses=min_poses,
        camera_poses=camera_poses,
        refine_targets=refine_targets,
    )
    net, cams, M, seen = drive.calibration, drive.true_cameras, drive.poses, drive.seen
    errors = []
    for cal in net.cameras:
        true = next(cm for cm in cams if cm.name == cal.name)
        err = calibration_errors(cal, true)
        errors.append(
            CameraCalibrationError(
                name=cal.name,
                focal_error_pct=err.focal_pct,
                position_error_m=err.position_m,
                rotation_error_deg=err.rotation_deg,
                poses_seen=cal.poses_seen,
                rms_px=cal.rms,
            )
        )
    return NetworkCalibrationResult(
        scenario="network-calibration",
        seed=seed,
        target_kind="marker",
        poses=M,
        detections=int(seen.sum()),
        placement_sigma_m=placement_sigma,
        distortion="known (the scene's true coefficients), held fixed",
        cameras=tuple(errors),
        rejected=tuple(RejectedCameraReport(r.name, r.reason, r.poses_seen) for r in net.rejected),
    )


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


def _board_roi(grey: NDArray[np.uint8], background: NDArray[np.uint8], pad: int) -> Any:
    """Return the box (x0, y0, x1, y1) around the near-black and near-white pixels of what
    differs from the empty-room frame (a printed board's squares), or None when there are too
    few of either (the robot's back or the board's back faces the camera, or nothing moved)."""
    moved = cv2.absdiff(grey, background) > 30
    dark = moved & (grey < 50)
    light = moved & (grey > 215)
    if np.count_nonzero(dark) < _MIN_INK or np.count_nonzero(light) < _MIN_INK:
        return None
    ink = cv2.morphologyEx(
        (dark | light).astype(np.uint8), cv2.MORPH_OPEN, np.ones((2, 2), np.uint8)
    )
    ys, xs = np.nonzero(ink)
    if len(xs) < 2 * _MIN_INK:
        return None
    h, w = grey.shape
    return (
        max(int(xs.min()) - pad, 0),
        max(int(ys.min()) - pad, 0),
        min(int(xs.max()) + pad + 1, w),
        min(int(ys.max()) + pad + 1, h),
    )


def detect_board(
    image: Any, background: Any, inner_corners: tuple[int, int], *, scale: float = 1.5
) -> Array | None:
    """Return the board's inner corners (N, 2) pixels found in a BGR frame (H, W, 3), or None.

    The search is confined to the near-black and near-white pixels (a printed board's squares)
    among those that differ from `background` (a frame of the same camera without the robot,
    as a background model holds it). So the tiled floor, whose tiles form a chessboard of their
    own, is not searched, and the detector runs on a small box; the box is enlarged
    `scale` times (cubic) so that the board's ~10 px squares suit the detector
    (core.calibration.find_chessboard), and the corners are mapped back and refined on the
    original pixels (cv2.cornerSubPix). On the default home: 0.08 px RMS per axis against the
    rendered truth, where the enlarged image alone gives 0.2 px.
    """
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    bg = cv2.cvtColor(background, cv2.COLOR_BGR2GRAY)
    roi = _board_roi(grey, bg, pad=10)
    if roi is None:
        return None
    x0, y0, x1, y1 = roi
    crop = grey[y0:y1, x0:x1]
    big = cv2.resize(crop, None, fx=scale, fy=scale, interpolation=cv2.INTER_CUBIC)
    try:
        det = find_chessboard(big, inner_corners)
    except (PatternNotFound, InvalidInput):
        return None
    # Back to the crop (pixel k of the crop covers [k - 0.5, k + 0.5] scaled by `scale`), then
    # refined on the original pixels: interpolation smooths the saddle points and biases them.
    pts = ((det.corners + 0.5) / scale - 0.5).astype(np.float32).reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-3)
    cv2.cornerSubPix(crop, pts, (_REFINE_WIN, _REFINE_WIN), (-1, -1), crit)
    return np.asarray(pts.reshape(-1, 2), np.float64) + np.array([x0, y0])


def _distortion_error_px(est_dist: Array, true: CameraModel, region: Array | None = None) -> float:
    """Return the largest difference (pixels of the true focal length) between the estimated and
    the true distortion displacement, over the rays that land in the true image, or only those
    inside the convex hull of `region` (K, 2) pixels when given."""
    u, v = np.meshgrid(np.linspace(0, true.width - 1, 65), np.linspace(0, true.height - 1, 49))
    px = np.stack([u.ravel(), v.ravel()], 1)
    if region is not None:
        hull = cv2.convexHull(region.astype(np.float32)).reshape(-1, 2).astype(np.float64)
        px = px[_inside(px, hull)]
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

    The scene's robot board is mounted (enabled) if the scene carries it unmounted. Programme:
    as `network_calibration` (a grid of stops `spacing` metres apart, random yaw), the robot
    stopping within `placement_sigma` metres per axis and `yaw_sigma` radians of each scripted
    pose, which is what the calibration is told, with those standard deviations as its prior.
    Every camera that could hold the whole board renders every stop; the board's corners are
    found in the image by `detect_board` against an empty-room frame of the same camera (no
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
    board = scene.robot.board
    if not board.enabled:
        board = board.model_copy(update={"enabled": True})
        scene = scene.model_copy(update={"robot": scene.robot.model_copy(update={"board": board})})
    assert scene.robot is not None
    rng = np.random.default_rng(seed)
    renderer = Renderer(scene)
    points, T_rb = board_mounting(board)
    cams = [renderer.camera(cs.name) for cs in scene.cameras]
    people = world_state(scene, 0.0).people
    empty = WorldState(0.0, None, people)
    backgrounds = [renderer.render(cm.name, empty, rng=rng, noise=noise).image for cm in cams]

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
                c = detect_board(frame.image, backgrounds[k], board.inner_corners)
                if c is not None:
                    found[k, j], ok[k, j] = c, True
        return np.column_stack([stops, yaw]), found, ok

    grid = _free_floor_grid(scene, spacing, scene.robot.base_radius + 0.05)
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
        err = calibration_errors(cal, true)
        errors.append(
            CameraCalibrationError(
                name=cal.name,
                focal_error_pct=err.focal_pct,
                position_error_m=err.position_m,
                rotation_error_deg=err.rotation_deg,
                poses_seen=cal.poses_seen,
                rms_px=cal.rms,
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
        placement_sigma_m=placement_sigma,
        distortion=f"estimated per camera (Zhang, {distortion})",
        cameras=tuple(errors),
        rejected=tuple(RejectedCameraReport(r.name, r.reason, r.poses_seen) for r in net.rejected),
    )


def _estimator_rmse(
    net: list[NetworkCamera],
    pixels: Array,
    vis: NDArray[np.bool_],
    truth: Array,
    height: float,
    sigma: float,
    pixel_cov: Array | None = None,
) -> tuple[dict[str, float], float, int]:
    """Return the RMSE per estimator (metres), the CRB root mean trace for the cameras ML
    used, and the number of targets every estimator located."""
    kw: dict[str, Any] = {"pixel_sigma": sigma, "pixel_cov": pixel_cov}
    lin = triangulate_linear(net, pixels, visible=vis, **kw)
    con = triangulate_on_plane(net, pixels, height, visible=vis, min_cameras=2, **kw)
    ml = locate_ml(net, pixels, height, visible=vis, min_cameras=2, **kw)
    # Monocular: each target from the first camera that sees it.
    first = np.argmax(vis, axis=0)
    mono_xy = np.full((pixels.shape[1], 2), np.nan)
    for k, cam in enumerate(net):
        sel = first == k
        if np.any(sel):
            mono_xy[sel] = locate_monocular(cam, pixels[k, sel], height, pixel_sigma=sigma).xy
    ok = lin.valid & con.valid & ml.valid & np.all(np.isfinite(mono_xy), axis=1)

    def rmse(xy: Array) -> float:
        return float(np.sqrt(np.mean(np.sum((xy[ok] - truth[ok]) ** 2, axis=1))))

    crb = cramer_rao_bound(
        net,
        truth[ok],
        height,
        pixel_sigma=sigma,
        pixel_cov=None if pixel_cov is None else pixel_cov[:, ok],
        visible=vis[:, ok],
    )
    out = {"mono": rmse(mono_xy), "linear": rmse(lin.xy), "constrained": rmse(con.xy)}
    out["ml"] = rmse(ml.xy)
    return out, crb.root_mean_trace, int(ok.sum())


def localization(
    scene: Scene | None = None,
    seed: int = 0,
    *,
    samples: int = 1500,
    sigma_px: float = 0.5,
    height: float = 0.36,
) -> LocalizationResult:
    """Return the estimators' RMSE on `samples` floor points at Z = `height` metres, each seen
    by >= 2 of the scene's (true) cameras, with pixels = projection + N(0, sigma_px^2 I)."""
    scene = scene or default_scene()
    rng = np.random.default_rng(seed)
    renderer = Renderer(scene)
    net = [nc for _, nc in _true_network(renderer)]
    if len(net) < 2:
        raise InvalidInput("the localization scenario needs a scene with >= 2 cameras")
    rooms = np.array([p for r in scene.rooms for p in r.polygon])
    lo, hi = rooms.min(0), rooms.max(0)
    pts: list[Array] = []
    have = 0
    for _ in range(50):
        cand = rng.uniform(lo, hi, (4 * samples, 2))
        X = np.column_stack([cand, np.full(len(cand), height)])
        vis = np.stack([renderer.sees(nc.name, X) & nc.in_view(X) for nc in net])
        keep = cand[vis.sum(0) >= 2]
        pts.append(keep)
        have += len(keep)
        if have >= samples:
            break
    truth = np.concatenate(pts)[:samples]
    if len(truth) < samples:
        raise InvalidInput("too few floor points are seen by two cameras in this scene")
    X = np.column_stack([truth, np.full(len(truth), height)])
    vis = np.stack([renderer.sees(nc.name, X) & nc.in_view(X) for nc in net])
    pixels = np.stack([nc.project(X) for nc in net])
    pixels = pixels + sigma_px * rng.standard_normal(pixels.shape)
    rmse, crb, n = _estimator_rmse(net, pixels, vis, truth, height, sigma_px)
    return LocalizationResult("localization", seed, n, sigma_px, rmse, crb)


def localization_images(
    scene: Scene | None = None,
    seed: int = 0,
    *,
    samples: int = 150,
    noise: SensorNoise | None = _DEFAULT_NOISE,
) -> LocalizationResult:
    """Return the estimators' RMSE on the robot marker detected in rendered images.

    The robot stands at `samples` random free floor poses seen by >= 2 cameras; each camera
    renders, the marker is detected (pixel and covariance from the detector); the estimators
    use the detector's covariances. `measured_sigma_px` is the RMS per-axis error of the
    detections against the marker's true image centre (ground truth used only for scoring);
    `sigma_px` the mean per-axis standard deviation the detector claimed.
    """
    scene = scene or default_scene()
    if scene.robot is None or scene.robot.marker is None:
        raise InvalidInput("localization-images needs a scene whose robot carries a marker")
    rng = np.random.default_rng(seed)
    renderer = Renderer(scene)
    pairs = _true_network(renderer)
    net = [nc for _, nc in pairs]
    marker = scene.robot.marker
    h = marker.height
    free = _free_floor_grid(scene, 0.1, scene.robot.base_radius + 0.1)
    cand = free[rng.permutation(len(free))]
    X = np.column_stack([cand, np.full(len(cand), h)])
    sees = np.stack([renderer.sees(nc.name, X) & nc.in_view(X) for nc in net])
    cand = cand[sees.sum(0) >= 2][:samples]
    C, B = len(net), len(cand)
    pixels = np.zeros((C, B, 2))
    cov = np.tile(np.eye(2), (C, B, 1, 1))
    vis = np.zeros((C, B), bool)
    err: list[Array] = []
    cfg = MarkerDetectorConfig(colour=marker.colour)
    for j, (x, y) in enumerate(cand):
        # Yaw 0 and a centred marker (offset (0, 0) in the default robot) put it over (x, y).
        state = world_state(scene, 0.0, Pose2D(float(x), float(y), 0.0))
        for k, nc in enumerate(net):
            frame = renderer.render(nc.name, state, rng=rng, noise=noise)
            det = detect_marker(frame.image, cfg)
            if det is None:
                continue
            pixels[k, j], cov[k, j], vis[k, j] = det.pixel, det.cov, True
            if frame.marker_ellipse_pixel is not None:
                err.append(det.pixel - frame.marker_ellipse_pixel)
    two = vis.sum(0) >= 2
    truth = cand + np.array(marker.offset)
    claimed = float(np.sqrt(np.mean(cov[vis][:, [0, 1], [0, 1]])))
    rmse, crb, n = _estimator_rmse(
        net, pixels[:, two], vis[:, two], truth[two], h, claimed, cov[:, two]
    )
    e = np.array(err)
    measured = float(np.sqrt(np.mean(e**2))) if len(e) else float("nan")
    return LocalizationResult("localization-images", seed, n, claimed, rmse, crb, measured)


SCENARIOS: dict[str, Callable[..., ScenarioResult]] = {
    "network-calibration": network_calibration,
    "network-calibration-board": network_calibration_board,
    "localization": localization,
    "localization-images": localization_images,
}

DESCRIPTIONS: dict[str, str] = {
    "network-calibration": "calibrate every ceiling camera by driving the robot's marker",
    "network-calibration-board": "calibrate every ceiling camera (with its lens) by driving "
    "the robot's chessboard",
    "localization": "ground estimators vs the Cramer-Rao bound on noisy true projections",
    "localization-images": "ground estimators on the robot marker detected in rendered images",
}


def run_scenario(name: str, scene: Scene | None = None, seed: int = 0) -> ScenarioResult:
    """Return the metrics of the scenario called `name` on `scene` (default home) with `seed`.

    Raises InvalidInput naming the known scenarios when `name` is not one of them.
    """
    fn = SCENARIOS.get(name)
    if fn is None:
        raise InvalidInput(f"unknown scenario {name!r}; known: {', '.join(SCENARIOS)}")
    return fn(scene, seed)
