"""Calibration drives in the twin: what an installer and the robot do to calibrate the network.

1. `show_chessboard`: a printed chessboard is held up in front of each ceiling camera in a
   series of poses, each frame is rendered, the board's corners are found against the empty
   room (core.calibration.find_chessboard_on_background) and each camera gets its own Zhang
   calibration (intrinsics, distortion, their covariance). The installer places the board by
   looking at the live image (the twin places it with the camera's pose, as a person watching
   the picture would); only the detected corners reach the calibration.
2. `drive_stops`: the robot really drives from its start pose to a programme of stops over the
   free floor (shortest paths through the doors, `core.sim._floor.FloorRoutes`), steered by its
   odometry, as the unicycle with wheel slip of core.sim.motion; at each stop it waits `dwell`
   seconds for the images. What the calibration is told is the odometry between the stops
   (core.calibration.network.odometry_prior) with its covariance from the base's slip model.
3. `observe_marker`: every camera sees the robot's marker at every stop: rendered and detected
   in the image (`mode="images"`), or its true projection plus Gaussian noise of `sigma_px`
   (`mode="projections"`, for studies of the pixel noise); `sigma_px` measured against the
   true image centre is returned beside them (truth used only to score). A robot with a
   telescopic mast raises it for the drive: its disc, 1.2 m up on the default robot, is seen
   with the top marker, and a marker above another gives each camera its tilt at every stop.
4. `drive_marker_calibration`: 1-3 and core.calibration.network.calibrate_network_marker.

The true cameras and the true stops are returned for scoring only (`calibration_errors`,
`marker_network_bound`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

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
    CameraBound,
    IntrinsicsPrior,
    NetworkCalibration,
    OdometryPrior,
    SlipModel,
    calibrate_network_marker,
    floor_gauge_projector,
    marker_network_bound,
    odometry_prior,
)
from core.calibration.zhang import CameraCalibration, calibrate_camera
from core.errors import (
    ConvergenceError,
    DegenerateConfiguration,
    InvalidInput,
    NotEnoughPoints,
    PatternNotFound,
)
from core.geometry.camera import project_points, undistort_points
from core.geometry.rotations import matrix_to_rotvec, rotvec_to_matrix
from core.localization.detect import MarkerDetectorConfig, detect_marker
from core.sim._floor import FloorRoutes, inside
from core.sim.motion import Patrol, Pose2D, UnicycleBase, WorldState, world_state
from core.sim.render import CameraModel, Renderer, SensorNoise
from core.sim.scene import Board, Robot, Scene, raise_mast

Array = NDArray[np.float64]

_DEFAULT_NOISE = SensorNoise()

#: The installer's printed board: 9 x 6 inner corners of 4 cm (a 40 cm x 28 cm print).
HANDHELD_BOARD = Board(inner_corners=(9, 6), square_size=0.04, margin=1.0)


# --------------------------------------------------------------------------------------------
# 1. Each camera's own calibration


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


# --------------------------------------------------------------------------------------------
# 2. The drive


@dataclass(frozen=True)
class Drive:
    """A driven programme of stops: `true_poses` (M, 3) where the robot really stood (scoring
    only), `odometry` the prior the calibration gets (start pose, increments, covariance),
    `times` (M,) s at which the images were taken, `duration_s` the whole drive's simulated
    time, `length_m` the distance driven (by odometry), `path_true` and `path_odometry`
    (N, 3) every step's true and odometry pose (for display)."""

    true_poses: Array
    odometry: OdometryPrior
    times: Array
    duration_s: float
    length_m: float
    path_true: Array = field(repr=False)
    path_odometry: Array = field(repr=False)


def plan_stops(
    scene: Scene, stops: int, rng: np.random.Generator, *, order: str = "nearest"
) -> Array:
    """Return `stops` floor positions (M, 2) spread over the free floor, in the order the robot
    visits them: a first straight leg ahead of the start pose (two stops 0.4 and 0.8 m ahead,
    where free), then the others nearest first (`order` "nearest") or in random order
    ("random": more crossings between the rooms, a much longer drive)."""
    if scene.robot is None:
        raise InvalidInput("a calibration drive needs a scene with a robot")
    routes = FloorRoutes(scene, scene.robot.base_radius + 0.1, spacing=0.1)
    cand = routes.points[rng.permutation(len(routes.points))]
    # The first leg goes straight ahead from the start: the only motion whose odometry ties
    # the start's heading (the world frame's x axis) to what the cameras see, before turns
    # add their heading noise.
    x0, y0, yaw0 = scene.robot.start
    lead: list[Array] = []
    for d in (0.4, 0.8):
        p = np.array([x0 + d * math.cos(yaw0), y0 + d * math.sin(yaw0)])
        if np.min(np.sum((routes.points - p) ** 2, axis=1)) <= 0.08**2 and len(lead) < stops:
            lead.append(p)
    # Spread over the floor: stops at least 0.6 of the mean spacing apart (of the free floor's
    # area shared out), relaxed when the floor cannot hold that many.
    sep = 0.6 * math.sqrt(0.01 * len(routes.points) / max(stops, 1))
    chosen: list[Array] = []
    while len(chosen) + len(lead) < stops and sep > 0.05:
        for p in cand:
            if len(chosen) + len(lead) >= stops:
                break
            near = [*lead, *chosen]
            if not near or np.min(np.sum((np.array(near) - p) ** 2, axis=1)) >= sep**2:
                chosen.append(p)
        sep *= 0.7
    pts = np.array(chosen).reshape(-1, 2)
    if order == "random":
        return np.vstack([np.array(lead).reshape(-1, 2), pts])
    if order != "nearest":
        raise InvalidInput(f"unknown stop order {order!r}; use 'nearest' or 'random'")
    visit = []
    here = lead[-1] if lead else np.array(scene.robot.start[:2])
    left = list(range(len(pts)))
    while left:
        k = min(left, key=lambda i: float(np.sum((pts[i] - here) ** 2)))
        visit.append(k)
        left.remove(k)
        here = pts[k]
    return np.vstack([np.array(lead).reshape(-1, 2), pts[visit]])


class Driver:
    """The scene's robot driving a calibration programme, resumable stop by stop.

    The base (UnicycleBase: limits, wheel slip drawn from `rng`) follows the shortest free path
    to each stop (Patrol, steered by its odometry), brakes, and waits `dwell` seconds; the stop
    is recorded when it stands still. A segment is abandoned after `max_segment_s` seconds
    (the robot stops where it is).
    """

    def __init__(
        self,
        scene: Scene,
        rng: np.random.Generator,
        *,
        dt: float = 0.05,
        dwell: float = 1.0,
        max_segment_s: float = 120.0,
    ) -> None:
        if scene.robot is None:
            raise InvalidInput("a calibration drive needs a scene with a robot")
        self.robot = scene.robot
        self.routes = FloorRoutes(scene, self.robot.base_radius + 0.05, spacing=0.1)
        self.base = UnicycleBase.from_robot(self.robot, dt=dt, rng=rng)
        self.dt, self.dwell, self.max_segment_s = dt, dwell, max_segment_s
        self.true_path = [self.base.state.pose.as_array()]
        self.odo_path = [self.base.state.odometry.as_array()]
        self.idx: list[int] = []
        self.times: list[float] = []

    def visit(self, stops: Array) -> None:
        """Drive through the floor positions `stops` (K, 2) in order."""
        base, dt = self.base, self.dt
        for goal in np.asarray(stops, dtype=np.float64).reshape(-1, 2):
            here = np.array([base.state.odometry.x, base.state.odometry.y])
            path = self.routes.path(here, goal)
            patrol = Patrol(path, self.robot.limits, loop=False, tolerance=0.1)
            for _ in range(round(self.max_segment_s / dt)):
                st = base.step(*patrol.command(base.state.odometry))
                self.true_path.append(st.pose.as_array())
                self.odo_path.append(st.odometry.as_array())
                if patrol.done and st.v == 0.0 and st.omega == 0.0:
                    break
            for _ in range(round(self.dwell / dt)):
                st = base.step(0.0, 0.0)
                self.true_path.append(st.pose.as_array())
                self.odo_path.append(st.odometry.as_array())
            self.idx.append(len(self.odo_path) - 1)
            self.times.append(base.state.time)

    def drive(self) -> Drive:
        """Return the drive so far (at least one stop)."""
        if not self.idx:
            raise InvalidInput("the robot has not stopped anywhere yet")
        odo = np.array(self.odo_path)
        tru = np.array(self.true_path)
        slip = SlipModel(**self.robot.slip.model_dump())
        prior = odometry_prior(odo, self.idx, slip)
        length = float(np.sum(np.linalg.norm(np.diff(odo[:, :2], axis=0), axis=1)))
        return Drive(
            tru[self.idx], prior, np.array(self.times), self.base.state.time, length, tru, odo
        )


def drive_stops(scene: Scene, stops: Array, rng: np.random.Generator, **options: float) -> Drive:
    """Return the drive of the scene's robot from its start pose through `stops` (M, 2)
    (`Driver`; options dt, dwell, max_segment_s)."""
    driver = Driver(scene, rng, **options)
    driver.visit(stops)
    return driver.drive()


def revisit_stops(
    routes: FloorRoutes, seen_xy: Array, count: int, rng: np.random.Generator
) -> Array:
    """Return up to `count` new stops (K, 2) spread over the free floor within 0.3 m (0.8 m
    when fewer than 6) of the convex hull of `seen_xy` (the odometry positions where a camera
    saw the marker): more of that camera's view, known from its detections alone."""
    if count <= 0 or len(seen_xy) == 0:
        return np.zeros((0, 2))
    pts = routes.points
    # A few detections outline the view poorly: reach further around them.
    reach = 0.3 if len(seen_xy) >= 6 else 0.8
    if len(seen_xy) >= 3:
        hull = cv2.convexHull(seen_xy.astype(np.float32)).reshape(-1, 2).astype(np.float64)
        a, b = hull, np.roll(hull, -1, axis=0)
        d = b - a
        t = np.clip(
            np.einsum("pkj,kj->pk", pts[:, None, :] - a[None], d) / np.sum(d * d, axis=1), 0, 1
        )
        dist = np.min(np.linalg.norm(pts[:, None, :] - (a + t[..., None] * d), axis=2), axis=1)
        near = inside(pts, hull) | (dist <= reach)
    else:
        near = np.min(np.linalg.norm(pts[:, None, :] - seen_xy[None], axis=2), axis=1) <= reach
    cand = pts[near][rng.permutation(int(near.sum()))]
    out: list[Array] = []
    sep = 0.6 * math.sqrt(0.01 * len(cand) / count) if len(cand) else 0.0
    while len(out) < min(count, len(cand)) and sep > 0.02:
        for p in cand:
            if len(out) >= count:
                break
            if not out or np.min(np.sum((np.array(out) - p) ** 2, axis=1)) >= sep**2:
                out.append(p)
        sep *= 0.7
    # Visit them nearest first from the first.
    if not out:
        return np.zeros((0, 2))
    left, order = list(range(1, len(out))), [0]
    while left:
        k = min(left, key=lambda i: float(np.sum((out[i] - out[order[-1]]) ** 2)))
        order.append(k)
        left.remove(k)
    return np.array(out)[order]


# --------------------------------------------------------------------------------------------
# 3. Observations of the marker


@dataclass(frozen=True)
class MarkerObservations:
    """Each camera's view of the marker at each stop: `pixels` (C, M, 2), `cov` (C, M, 2, 2)
    px^2 (the detector's, or sigma^2 I), `visible` (C, M), `areas` (C, M) the detected blobs'
    covered areas in pixels (NaN unseen or for projections), and `errors` the pixels minus
    the marker's true image centre (scoring only; `sigma_px` their RMS per axis)."""

    pixels: Array
    cov: Array
    visible: NDArray[np.bool_]
    errors: Array = field(repr=False)  # (K, 2) px, detections minus truth (scoring only)
    areas: Array | None = None
    mast: MarkerObservations | None = None

    def stacked(self) -> tuple[Array, Array, NDArray[np.bool_], Array | None]:
        """Return pixels (C, M, K, 2), covariances (C, M, K, 2, 2), visible (C, M, K) and
        areas (C, M, K) (None when unknown) of the K markers: the top one, then the mast's."""
        parts = [self] if self.mast is None else [self, self.mast]
        areas = None
        if all(p.areas is not None for p in parts):
            areas = np.stack([p.areas for p in parts], axis=2)  # type: ignore[misc]
        return (
            np.stack([p.pixels for p in parts], axis=2),
            np.stack([p.cov for p in parts], axis=2),
            np.stack([p.visible for p in parts], axis=2),
            areas,
        )

    @property
    def sigma_px(self) -> float:
        """RMS error per axis of the pixels against the marker's true image centre."""
        e = self.errors
        return float(np.sqrt(np.mean(e**2))) if len(e) else float("nan")

    def joined(self, other: MarkerObservations) -> MarkerObservations:
        """Return these observations followed by `other`'s stops."""
        areas = None
        if self.areas is not None and other.areas is not None:
            areas = np.concatenate([self.areas, other.areas], axis=1)
        mast = None
        if self.mast is not None and other.mast is not None:
            mast = self.mast.joined(other.mast)
        return MarkerObservations(
            np.concatenate([self.pixels, other.pixels], axis=1),
            np.concatenate([self.cov, other.cov], axis=1),
            np.concatenate([self.visible, other.visible], axis=1),
            np.concatenate([self.errors, other.errors]),
            areas,
            mast,
        )

    def capped(self, visible: NDArray[np.bool_]) -> MarkerObservations:
        """Return these observations seen only where `visible` (C, M) also holds (every
        marker)."""
        mast = None if self.mast is None else self.mast.capped(visible)
        return MarkerObservations(
            self.pixels, self.cov, self.visible & visible, self.errors, self.areas, mast
        )


def observe_marker(
    renderer: Renderer,
    drive: Drive,
    rng: np.random.Generator,
    *,
    mode: str = "images",
    sigma_px: float = 0.5,
    noise: SensorNoise | None = _DEFAULT_NOISE,
    first: int = 0,
) -> MarkerObservations:
    """Return what every camera sees of the robot's marker (and of its mast marker, when it
    has one: `MarkerObservations.mast`) at the stops of `drive` from `first` on (module
    docstring, 3). Raises InvalidInput for an unknown mode or a robot without marker."""
    scene = renderer.scene
    if scene.robot is None or scene.robot.marker is None:
        raise InvalidInput("observing the marker needs a scene whose robot carries a marker")
    if mode not in ("images", "projections"):
        raise InvalidInput(f"unknown observation mode {mode!r}; use 'images' or 'projections'")
    if mode == "projections" and not sigma_px > 0:
        raise InvalidInput(f"sigma_px must be > 0 pixels, got {sigma_px}")
    markers = [scene.robot.marker]
    if scene.robot.mast_marker is not None:
        markers.append(scene.robot.mast_marker)
    cams = [renderer.camera(c.name) for c in scene.cameras]
    P = drive.true_poses[first:]
    times = drive.times[first:]
    C, M, K = len(cams), len(P), len(markers)
    c, s = np.cos(P[:, 2]), np.sin(P[:, 2])
    pixels = np.zeros((K, C, M, 2))
    cov = np.tile(np.eye(2), (K, C, M, 1, 1))
    vis = np.zeros((K, C, M), bool)
    areas = np.full((K, C, M), np.nan)
    errs: list[list[Array]] = [[] for _ in markers]
    if mode == "projections":
        for i, mk in enumerate(markers):
            off = mk.offset
            X = np.column_stack(
                [
                    P[:, 0] + c * off[0] - s * off[1],
                    P[:, 1] + s * off[0] + c * off[1],
                    np.full(M, mk.height),
                ]
            )
            for k, cam in enumerate(cams):
                vis[i, k] = renderer.sees(cam.name, X)
                e = sigma_px * rng.standard_normal((M, 2))
                pixels[i, k] = cam.project(X) + e
                errs[i].append(e[vis[i, k]])
        cov[:] = sigma_px**2 * np.eye(2)
        areas[:] = np.nan
    else:
        cfgs = [MarkerDetectorConfig(colour=mk.colour) for mk in markers]
        for j in range(M):
            state = world_state(scene, float(times[j]), Pose2D(*P[j]))
            for k, cam in enumerate(cams):
                frame = renderer.render(cam.name, state, rng=rng, noise=noise)
                truths = [frame.marker_ellipse_pixel, frame.mast_marker_ellipse_pixel]
                for i, cfg in enumerate(cfgs):
                    det = detect_marker(frame.image, cfg, background=renderer.empty(cam.name))
                    if det is None:
                        continue
                    pixels[i, k, j], cov[i, k, j], vis[i, k, j] = det.pixel, det.cov, True
                    areas[i, k, j] = det.area
                    truth = truths[i]
                    if truth is not None:
                        errs[i].append((det.pixel - truth)[None])
    out = None
    for i in reversed(range(K)):
        e = np.concatenate(errs[i]) if errs[i] else np.zeros((0, 2))
        out = MarkerObservations(pixels[i], cov[i], vis[i], e, areas[i], out)
    assert out is not None
    return out


def drive_and_observe(
    renderer: Renderer,
    rng: np.random.Generator,
    stops: int,
    *,
    mode: str = "images",
    sigma_px: float = 0.5,
    noise: SensorNoise | None = _DEFAULT_NOISE,
    revisit_below: int = 20,
    max_drive_s: float = 300.0,
) -> tuple[Drive, MarkerObservations]:
    """Return the drive through `stops` planned stops (`plan_stops`) and the marker's
    observations; then, for every camera that saw the marker at fewer than `revisit_below`
    stops, a second pass over more of its view (`revisit_stops`, from the odometry positions
    of its own detections, the cameras that saw least first), observed too. A stop is only
    driven to when the drive, with it, is expected to last at most `max_drive_s` seconds."""
    scene = renderer.scene
    assert scene.robot is not None
    speed = scene.robot.limits.max_speed
    driver = Driver(scene, rng)

    def fits(stop: Array) -> bool:
        # Within the budget: the time so far, a generous estimate of the way there (half as
        # long again as the straight line, plus accelerating, braking and the dwell).
        odo = driver.base.state.odometry
        way = 1.5 * float(np.hypot(stop[0] - odo.x, stop[1] - odo.y)) / speed + 3.0
        return driver.base.state.time + way + driver.dwell <= max_drive_s

    for stop in plan_stops(scene, stops, rng):
        if fits(stop) or not driver.idx:
            driver.visit(stop)
    drive = driver.drive()
    obs = observe_marker(renderer, drive, rng, mode=mode, sigma_px=sigma_px, noise=noise)
    odo_xy = drive.odometry.poses[:, :2]
    extra = []
    for k in np.argsort(obs.visible.sum(1)):
        n = int(obs.visible[k].sum())
        if n < revisit_below:
            extra.append(
                revisit_stops(driver.routes, odo_xy[obs.visible[k]], revisit_below - n, rng)
            )
    more = np.concatenate(extra) if extra else np.zeros((0, 2))
    first = len(drive.true_poses)
    for stop in more:
        if fits(stop):
            driver.visit(stop)
    if len(driver.idx) > first:
        drive = driver.drive()
        obs = obs.joined(
            observe_marker(
                renderer, drive, rng, mode=mode, sigma_px=sigma_px, noise=noise, first=first
            )
        )
    return drive, obs


# --------------------------------------------------------------------------------------------
# 4. The whole calibration


@dataclass(frozen=True)
class PoseErrors:
    """Errors of a calibrated camera against the twin's true camera: focal length (% of the
    true mean focal length, signed), position (m) and orientation (degrees)."""

    focal_pct: float
    position_m: float
    rotation_deg: float


def calibration_errors(cal: CalibratedCamera, true: CameraModel) -> PoseErrors:
    """Return the errors of `cal` against the scene's camera `true` (scoring)."""
    f_true = 0.5 * (true.K[0, 0] + true.K[1, 1])
    rot = matrix_to_rotvec(cal.R @ true.R_camera_world.T)
    return PoseErrors(
        focal_pct=float(100 * (cal.focal - f_true) / f_true),
        position_m=float(np.linalg.norm(cal.position - true.position)),
        rotation_deg=float(np.degrees(np.linalg.norm(rot))),
    )


def aligned_errors(
    cals: list[CalibratedCamera], trues: list[CameraModel]
) -> list[tuple[float, float]]:
    """Return each camera's (position m, orientation degrees) error after removing the floor
    rigid motion (x, y, yaw) that best aligns the calibrated centres to the true ones
    (core.calibration.network.floor_gauge_projector, first order): the error of the network's
    own geometry. NaN with fewer than 2 cameras (scoring)."""
    if len(cals) < 2:
        return [(float("nan"), float("nan"))] * len(cals)
    e = np.zeros(6 * len(cals))
    for k, (cal, true) in enumerate(zip(cals, trues, strict=True)):
        e[6 * k : 6 * k + 3] = cal.position - true.position
        e[6 * k + 3 : 6 * k + 6] = matrix_to_rotvec(cal.R.T @ true.R_camera_world)
    a = floor_gauge_projector([t.position for t in trues]) @ e
    return [
        (
            float(np.linalg.norm(a[6 * k : 6 * k + 3])),
            float(np.degrees(np.linalg.norm(a[6 * k + 3 : 6 * k + 6]))),
        )
        for k in range(len(cals))
    ]


@dataclass(frozen=True)
class MarkerDrive:
    """A marker calibration drive: the network `calibration`, the cameras' own `intrinsics`
    session, the `drive` and the `observations`; `true_cameras` for scoring, and `bound` the
    Cramer-Rao bound of each calibrated camera (scoring and planning)."""

    calibration: NetworkCalibration
    intrinsics: BoardSession
    drive: Drive
    observations: MarkerObservations
    true_cameras: tuple[CameraModel, ...]
    bound: tuple[CameraBound, ...]

    @property
    def poses(self) -> int:
        """Number of stops."""
        return len(self.drive.true_poses)

    @property
    def seen(self) -> NDArray[np.bool_]:
        """Which camera saw the marker at which stop (C, M)."""
        return self.observations.visible


def bound_for(
    net_names: list[str],
    session: BoardSession,
    cams: list[CameraModel],
    drive: Drive,
    obs: MarkerObservations,
    robot: Robot,
) -> tuple[CameraBound, ...]:
    """Return the Cramer-Rao bound of the cameras `net_names` (scoring: it reads the truth)
    calibrated by the robot's markers (`robot_markers`)."""
    k_of = {cm.name: k for k, cm in enumerate(cams)}
    sel = [k_of[n] for n in net_names]
    if not sel:
        return ()
    heights, offsets, _ = robot_markers(robot)
    _, cov, seen, _ = obs.stacked()
    return marker_network_bound(
        net_names,
        session.priors(net_names),
        [cams[k].K for k in sel],
        [cams[k].dist for k in sel],
        [cams[k].R_camera_world for k in sel],
        [cams[k].t_camera_world for k in sel],
        drive.true_poses,
        seen[sel],
        drive.odometry,
        heights,
        offset=offsets,
        pixel_cov=cov[sel],
    )


def drive_marker_calibration(
    scene: Scene,
    seed: int,
    *,
    stops: int = 32,
    mode: str = "images",
    sigma_px: float = 0.5,
    noise: SensorNoise | None = _DEFAULT_NOISE,
    board_views: int = 16,
    revisit_below: int = 20,
    min_poses: int = 6,
    camera_poses: dict[str, int] | None = None,
    renderer: Renderer | None = None,
    max_drive_s: float = 300.0,
) -> MarkerDrive:
    """Return the network calibration of the scene's cameras by the robot's marker (module
    docstring): each camera's own chessboard calibration, a drive through `stops` stops with
    a second pass for cameras that saw fewer than `revisit_below` (`drive_and_observe`), the
    marker observed (`mode`, `sigma_px`) and the joint calibration. `camera_poses` optionally
    caps how many stops a named camera sees (robustness checks); `renderer` reuses one whose
    static layers are built; `max_drive_s` bounds the drive's simulated length (seconds). The
    robot's telescopic mast, if it has one, is raised for the drive (core.sim.scene.raise_mast).
    Raises InvalidInput for a scene without cameras or marker."""
    if scene.robot is None or scene.robot.marker is None:
        raise InvalidInput("network-calibration needs a scene whose robot carries a marker")
    if not scene.cameras:
        raise InvalidInput("network-calibration needs a scene with cameras")
    if stops < 4:
        raise InvalidInput(f"a calibration drive needs at least 4 stops, got {stops}")
    scene = raise_mast(scene)
    assert scene.robot is not None  # raising the mast keeps the robot
    rng = np.random.default_rng(seed)
    renderer = renderer.for_scene(scene) if renderer is not None else Renderer(scene)
    session = show_chessboard(renderer, rng, views=board_views, noise=noise)
    drive, obs = drive_and_observe(
        renderer,
        rng,
        stops,
        mode=mode,
        sigma_px=sigma_px,
        noise=noise,
        revisit_below=revisit_below,
        max_drive_s=max_drive_s,
    )
    cams = [renderer.camera(c.name) for c in scene.cameras]
    names = [cm.name for cm in cams]
    vis = obs.visible.copy()
    for name, cap in (camera_poses or {}).items():
        if name not in names:
            raise InvalidInput(f"camera_poses names an unknown camera {name!r}")
        k = names.index(name)
        vis[k, np.flatnonzero(vis[k])[cap:]] = False
    obs = obs.capped(vis)
    heights, offsets, radii = robot_markers(scene.robot)
    pixels, cov, seen, areas = obs.stacked()
    net = calibrate_network_marker(
        names,
        session.priors(names),
        pixels,
        seen,
        drive.odometry,
        heights,
        offset=offsets,
        radius=radii if mode == "images" else 0.0,
        pixel_cov=cov,
        areas=areas,
        min_poses=min_poses,
    )
    done = [c.name for c in net.cameras]
    bound = bound_for(done, session, cams, drive, obs, scene.robot)
    return MarkerDrive(net, session, drive, obs, tuple(cams), bound)


def robot_markers(robot: Robot) -> tuple[Array, Array, Array]:
    """Return the heights (K,), offsets (K, 2) and radii (K,) of the robot's markers: its top
    marker, then its mast marker when it has one (the calibration's marker layout)."""
    ms = [m for m in (robot.marker, robot.mast_marker) if m is not None]
    return (
        np.array([m.height for m in ms]),
        np.array([m.offset for m in ms], dtype=np.float64).reshape(-1, 2),
        np.array([m.radius for m in ms]),
    )
