"""Projector and spot-following scenarios of the twin (spec 03).

* `path-following` (`path_following`): a tour of the living room (about 10 m) planned leg by
  leg on the inflated floor plan (core.navigation.plan_path), drawn by the projector at
  0.3 m/s (core.projector.project_path, with the projector's calibrated model), and followed
  by the robot with each of the three laws on the same path, the same slip and the same camera
  noise (one seed): the floor camera at 15 Hz with 100 ms latency and pixel noise, the spot
  back-projected on the floor plane from the camera's own one-view calibration. Errors are the
  distance between the robot's control point and the true spot, against the twin.
* `projector-calibration` (`projector_calibration`): 14 commanded spots located on the floor by
  the ceiling cameras and T_world_base estimated by the sparse LM; its errors against the twin.

The twin's projector. The scene gives the projector's nominal mount (what the installer
entered); the twin's true unit departs from it by a seeded mounting error (`MOUNT_ERROR_*`) and
carries small Denavit-Hartenberg offsets (`TRUE_OFFSETS`), as a real unit does. Estimators only
ever see the nominal model, the commanded angles and the measurements.

The floor camera. The scene's robot carries one onboard camera, mounted level; spot following
needs the floor camera spec 07 describes (tilted down, seeing the floor from ~0.3 m ahead), so
it is defined here (`FLOOR_CAMERA_*`) until the scene schema carries it.

What is measured: the floor camera's frames are rendered from the robot's true pose (the home,
and the spot's red light where the camera sees it: core.sim.render), 15 a second, and the spot
is found in each by core.navigation.detect_laser_spot (no laser-off frame: the camera moves),
then given SPOT_PIXEL_SIGMA of extra pixel noise and dropped at random (DETECTION_PROBABILITY,
glints and motion blur the renderer does not draw). The floor camera's intrinsics come from its
own Zhang calibration on rendered chessboard views (`floor_camera_intrinsics`,
core.sim.intrinsics), its plane from one rendered view of a floor chessboard on those
intrinsics (`calibrate_floor_camera`): no estimator reads the true lens (FLOOR_CAMERA_K,
FLOOR_CAMERA_DIST), which only forms the images. Without a renderer (unit tests)
the spot's true projection stands in for the detection. In
`projector-calibration` each ceiling camera's frame of the home is rendered (core.sim.render)
with the laser's light added where the spot's image falls, when the camera sees it (in view,
not hidden by walls or furniture), and the spot is detected in it by
core.navigation.detect_laser_spot; the spots are then located on the floor by
core.localization.locate_ml with the cameras' *calibrated* models, the marker network
calibration of the same seed (core.sim.scenarios.multi_target_tracking.calibrated_cameras), so
their errors include that calibration's.
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from shapely.geometry import LineString

from core.calibration import Chessboard, board_object_points, find_chessboard
from core.calibration.onboard import FloorPlane, calibrate_floor_plane
from core.calibration.projector import calibrate_projector, mount_errors
from core.errors import InvalidInput
from core.geometry.camera import project_points
from core.geometry.poses import pose_from_quaternion
from core.geometry.rotations import matrix_to_rotvec, rotvec_to_matrix
from core.localization import NetworkCamera
from core.localization.ground import locate_ml
from core.navigation import detect_laser_spot, occupancy_grid, plan_path
from core.navigation._control import (
    AdaptiveLaw,
    Limits,
    ProportionalLaw,
    Reference,
    SpotFollower,
    StateFeedbackLaw,
    TrackState,
    control_point,
)
from core.projector import JointTrajectory, PanTiltProjector, project_path
from core.sim.intrinsics import NOISE as INTRINSICS_NOISE
from core.sim.intrinsics import RenderedCalibration, calibrate_from_board_views, focal_error_pct
from core.sim.motion import Pose2D, UnicycleBase, WorldState
from core.sim.render import Renderer, camera_at, renderer_for
from core.sim.render.landmarks import LandmarkCamera
from core.sim.scene import Board, CeilingCamera, Scene, default_scene

Array = NDArray[np.float64]
# on_step(t, pose, spot, error) of simulate_following: s, (3,) x y theta, (2,) x y, m.
StepCallback = Callable[[float, Array, Array, float], None]

# The floor camera on the robot (robot frame: x forward, y left, z up): 0.15 m ahead of the
# axle, 0.40 m up, pitched 40 degrees down; 640 x 480, f = 500 px, mild barrel distortion.
# It sees the floor from about 0.33 m to 1.7 m ahead of the axle.
FLOOR_CAMERA_POSITION = (0.15, 0.0, 0.40)
FLOOR_CAMERA_PITCH = math.radians(40.0)
FLOOR_CAMERA_K = np.array([[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]])
FLOOR_CAMERA_DIST = np.array([-0.05, 0.01, 0.0, 0.0, 0.0])
FLOOR_CAMERA_SIZE = (640, 480)
# Sub-pixel spot centroid noise (px), a conservative bound: the detector's tests measure
# ~0.02 px on clean rendered blobs (tests/core/navigation/test_spot_detection.py).
SPOT_PIXEL_SIGMA = 0.3
# The floor camera under-exposes, as a laser-spot camera is set to: the floor sits at mid-grey
# and the laser, far brighter than the room, saturates the red channel (on a bright tile at
# full exposure the spot is only ~40 grey levels redder than the floor, below the detector's
# threshold).
FLOOR_CAMERA_EXPOSURE = 0.5
CAMERA_RATE = 15.0  # Hz
CAMERA_LATENCY = 0.1  # s from capture to the robot's controller
DETECTION_PROBABILITY = 0.98  # per frame with the spot in view (glints, motion blur)
CONTROL_DT = 0.02  # s, the controller's and the simulated base's step
LOOKAHEAD = 0.6  # m, the control point P ahead of the axle (in the floor camera's view)

# The living-room tour the spot draws (world x, y metres), planned leg by leg.
TOUR = ((1.6, 1.2), (3.6, 1.2), (3.6, 5.3), (2.9, 5.3), (2.9, 3.6), (0.8, 3.45))
SPOT_SPEED = 0.3  # m/s, cruising
# m/s^2, the spot's tangential and lateral acceleration bound (a gentle spot is one a
# follower can keep under: the adaptive law's error on a curve is about this over Gamma).
SPOT_ACCELERATION = 0.05
CORNER_RADIUS = 0.5  # m, the fillets rounding the planned path's corners
PLAN_RESOLUTION = 0.05
PLAN_MARGIN = 0.05
PLAN_SIMPLIFY = 0.03

# The twin's true projector departs from the scene's nominal mount by these (per axis,
# Gaussian standard deviations) and carries these DH offsets.
MOUNT_ERROR_POSITION = 0.03
MOUNT_ERROR_ANGLE = math.radians(1.0)
# A pan zero offset is a turn of the mount about the pan axis (not separable from it), so the
# twin folds it into the mount error.
TRUE_OFFSETS = {"theta": (0.0, -0.008), "d": (0.0, 0.0), "a": (0.0, 0.0)}
CEILING_PIXEL_SIGMA = 0.5
LASER_BLOB_SIGMA = 1.2


def nominal_projector(scene: Scene) -> PanTiltProjector:
    """Return the installer's model of the scene's projector: its nominal mount, ideal joints."""
    p = scene.projector
    if p is None:
        raise InvalidInput(f"scene {scene.name!r} has no projector")
    if p.pose.quaternion_xyzw is None:
        raise InvalidInput("the projector's pose must be given with quaternion_xyzw")
    return PanTiltProjector(
        pose_from_quaternion(p.pose.position, p.pose.quaternion_xyzw),
        pan_limits=p.pan_limits,
        tilt_limits=p.tilt_limits,
        max_rate=(p.max_rate, p.max_rate),
        max_acceleration=(4.0, 4.0),
    )


def twin_projector(scene: Scene, seed: int) -> PanTiltProjector:
    """Return the twin's true projector (for simulation and scoring only)."""
    nominal = nominal_projector(scene)
    rng = np.random.default_rng([seed, 3003])
    dT = np.eye(4)
    dT[:3, :3] = rotvec_to_matrix(rng.normal(0.0, MOUNT_ERROR_ANGLE, 3))
    dT[:3, 3] = rng.normal(0.0, MOUNT_ERROR_POSITION, 3)
    return PanTiltProjector(
        nominal.T_world_base @ dT,
        theta=np.array(TRUE_OFFSETS["theta"]),
        d=np.array(TRUE_OFFSETS["d"]),
        a=np.array(TRUE_OFFSETS["a"]),
        pan_limits=nominal.pan_limits,
        tilt_limits=nominal.tilt_limits,
        max_rate=nominal.max_rate,
        max_acceleration=nominal.max_acceleration,
    )


def floor_camera_mount() -> Array:
    """Return T_robot_cam (4, 4) of the floor camera (OpenCV camera axes)."""
    c, s = math.cos(FLOOR_CAMERA_PITCH), math.sin(FLOOR_CAMERA_PITCH)
    z = np.array([c, 0.0, -s])
    x = np.array([0.0, -1.0, 0.0])
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = FLOOR_CAMERA_POSITION
    return T


def _project_robot_points(T_robot_cam: Array, X_robot: Array) -> tuple[Array, NDArray[np.bool_]]:
    """Return (pixels (N, 2), in view (N,)) of robot-frame points in the floor camera."""
    T_cam_robot = np.linalg.inv(T_robot_cam)
    R, t = T_cam_robot[:3, :3], T_cam_robot[:3, 3]
    proj = project_points(X_robot, matrix_to_rotvec(R), t, FLOOR_CAMERA_K, FLOOR_CAMERA_DIST)
    w, h = FLOOR_CAMERA_SIZE
    uv = proj.points
    ok = (proj.depth > 0.05) & (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0)
    ok &= uv[:, 1] <= h - 1
    return uv, ok


# The floor pattern the floor camera is calibrated on: a chessboard of 0.1 m squares, 7 x 6
# inner corners (7 + 6 odd: its first corner is told from its last), laid flat 0.5 m to 1.1 m
# ahead of the robot, centred on its axis; the robot stands at FLOOR_PATTERN_POSE (world x, y,
# theta), where the living room's floor is free ahead of it.
FLOOR_PATTERN = Board(inner_corners=(7, 6), square_size=0.1, margin=0.5)
FLOOR_PATTERN_POSE = (1.6, 1.2, 0.0)


def robot_transform(pose: ArrayLike) -> Array:
    """Return T_world_robot (4, 4) of a base pose (x, y, theta)."""
    x, y, th = (float(v) for v in np.asarray(pose, dtype=np.float64).ravel()[:3])
    c, s = math.cos(th), math.sin(th)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:2, 3] = [x, y]
    return T


def floor_camera_at(pose: ArrayLike) -> CeilingCamera:
    """Return the floor camera of a robot at base pose (x, y, theta) as a renderable camera."""
    T = robot_transform(pose) @ floor_camera_mount()
    return camera_at("floor_camera", FLOOR_CAMERA_K, FLOOR_CAMERA_DIST, FLOOR_CAMERA_SIZE, T)


def _floor_pattern_points() -> tuple[Array, Array]:
    """Return (T_robot_board (4, 4), inner corners (N, 3) robot frame, detector order)."""
    cols, rows = FLOOR_PATTERN.inner_corners
    s = FLOOR_PATTERN.square_size
    # Columns run ahead (+x), rows to the right (-y): z = x cross y points down, the printed
    # face looks up. The print is drawn 0.5 mm above the floor (its thickness), its corners
    # taken on the floor.
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = [0.5, (rows - 1) * s / 2, 0.0]
    P = board_object_points(Chessboard(cols, rows), s) @ T[:3, :3].T + T[:3, 3]
    T[2, 3] = 5e-4
    return T, P


def floor_camera_intrinsics(rng: np.random.Generator) -> RenderedCalibration:
    """Return the floor camera's intrinsics as the robot's owner gets them: Zhang from
    rendered chessboard views through the floor camera's lens (core.sim.intrinsics)."""
    w, h = FLOOR_CAMERA_SIZE
    return calibrate_from_board_views(
        LandmarkCamera(FLOOR_CAMERA_K, FLOOR_CAMERA_DIST, w, h), rng, noise=INTRINSICS_NOISE
    )


def calibrate_floor_camera(
    rng: np.random.Generator,
    renderer: Renderer | None = None,
    intrinsics: RenderedCalibration | None = None,
) -> FloorPlane:
    """Return the floor camera's floor plane from one view of the floor pattern
    (FLOOR_PATTERN) laid ahead of the robot, on the camera's calibrated intrinsics
    (`intrinsics`, default: calibrated first from rendered chessboard views,
    floor_camera_intrinsics; never the twin's true lens). With a `renderer`, the view is
    rendered (the robot at FLOOR_PATTERN_POSE in the home) and the corners detected
    (core.calibration.find_chessboard); without one, the corners' true pixels plus 0.1 px of
    noise (what cv2.cornerSubPix achieves on chessboard corners). Raises PatternNotFound when
    the rendered pattern is not found."""
    cal = intrinsics if intrinsics is not None else floor_camera_intrinsics(rng)
    T_robot_board, pattern = _floor_pattern_points()
    if renderer is None:
        uv, ok = _project_robot_points(floor_camera_mount(), pattern)
        if not np.all(ok):
            raise InvalidInput("the floor pattern must lie inside the floor camera's view")
        uv = uv + rng.normal(0.0, 0.1, uv.shape)
        return calibrate_floor_plane(pattern, uv, cal.K, cal.dist, sigma=0.1)
    T_world_robot = robot_transform(FLOOR_PATTERN_POSE)
    frame = renderer.render_board(
        floor_camera_at(FLOOR_PATTERN_POSE), FLOOR_PATTERN, T_world_robot @ T_robot_board, rng=rng
    )
    uv = find_chessboard(frame.image, FLOOR_PATTERN.inner_corners).corners
    return calibrate_floor_plane(pattern, uv, cal.K, cal.dist)


def plan_tour(scene: Scene, waypoints: tuple[tuple[float, float], ...] = TOUR) -> Array:
    """Return the planned tour (N, 2): each leg between consecutive waypoints planned on the
    floor plan inflated by the robot's radius plus a margin, the legs joined."""
    radius = (scene.robot.base_radius if scene.robot else 0.2) + PLAN_MARGIN
    grid = occupancy_grid(scene, radius, PLAN_RESOLUTION)
    legs = [
        plan_path(grid.free, a, b, resolution=grid.resolution, origin=grid.origin)
        for a, b in itertools.pairwise(waypoints)
    ]
    path = np.vstack([legs[0]] + [leg[1:] for leg in legs[1:]])
    # The taut path hugs the inflated furniture's rounded corners in cell-sized steps; merge
    # them (Douglas-Peucker within PLAN_SIMPLIFY, less than the planning margin) so the spot
    # sweeps round them in one fillet.
    simple = LineString(path).simplify(PLAN_SIMPLIFY, preserve_topology=False)
    return np.asarray(simple.coords, dtype=np.float64)


@dataclass(frozen=True)
class FollowRun:
    """One law's run: `time` (N,) s, `error` (N,) m (|P - spot| against the twin), `pose`
    (N, 3) the robot's true pose (x, y m, theta rad), `spot` (N, 2) the true spot on the floor
    (x, y m), `state` (N,) the follower's state, `straight` (N,) whether the spot was cruising
    on a straight stretch for at least 3 s, `finished_s` the time the projector finished
    drawing (None if it never did), `lost_events`."""

    law: str
    time: Array
    error: Array
    pose: Array
    spot: Array
    state: NDArray[np.str_]
    straight: NDArray[np.bool_]
    finished_s: float | None
    lost_events: int

    @property
    def rms(self) -> float:
        """RMS error over the whole run (m)."""
        return float(np.sqrt(np.mean(self.error**2)))

    @property
    def steady(self) -> float:
        """RMS error on straight stretches at cruising speed, after 3 s on them (m)."""
        e = self.error[self.straight]
        return float(np.sqrt(np.mean(e**2))) if len(e) else float("nan")


def simulate_following(
    follower: SpotFollower,
    trajectory: JointTrajectory,
    projector: PanTiltProjector,
    plane: FloorPlane,
    start: Pose2D,
    scene: Scene,
    seed: int,
    *,
    settle: float = 3.0,
    on_step: StepCallback | None = None,
    renderer: Renderer | None = None,
) -> FollowRun:
    """Run one law in closed loop (module docstring) and return its errors against the twin.

    `projector` is the twin's true unit (it draws the spot from the commanded angles);
    `plane` the robot's own calibration of its floor camera; the noise streams (slip, pixels,
    missed frames) come from `seed` and are the same for every law. `on_step(t, pose, spot,
    error)`, when given, is called at every control step (CONTROL_DT) with the simulated time
    (s), the robot's true pose (3,), the true spot (2,) and the error (m) as the run records
    them, so a caller can show the run while it goes; it must not modify the arrays.

    `renderer`, when given, renders every floor-camera frame (the home from the robot's true
    pose, the spot's red light where the camera sees it) and core.navigation.detect_laser_spot
    finds the spot in it; without one the spot's true projection stands in for the detection.
    Both add SPOT_PIXEL_SIGMA of noise and drop frames at random (DETECTION_PROBABILITY).
    """
    robot = scene.robot
    if robot is None:
        raise InvalidInput(f"scene {scene.name!r} has no robot")
    base = UnicycleBase(robot.limits, robot.slip, start, dt=CONTROL_DT, rng=seed)
    cam_rng = np.random.default_rng([seed, 15])
    T_true = floor_camera_mount()
    # Nobody walks through this scenario: the walkers are kept out of the home.
    empty = WorldState(0.0, None, tuple((1e4, 1e4) for _ in scene.people))
    period = 1.0 / CAMERA_RATE
    next_capture = 0.0
    pending: deque[tuple[float, float, Array, Array]] = deque()
    tau = 0.0
    end = trajectory.duration
    times, errors, states, straight = [], [], [], []
    poses: list[Array] = []
    spots: list[Array] = []
    finished: float | None = None
    speed = np.linalg.norm(trajectory.spot_velocity, axis=1)
    _, _, turn = trajectory.reference(trajectory.t)
    cruising = (speed > 0.99 * speed.max()) & (np.abs(turn) < 1e-3)
    # Time on the current straight cruise, per sample of the trajectory.
    run = np.zeros(len(cruising))
    for k in range(1, len(cruising)):
        run[k] = run[k - 1] + (trajectory.t[k] - trajectory.t[k - 1]) if cruising[k] else 0.0
    max_time = end + 60.0
    # Where the twin's true unit puts the spot at every commanded sample (10 ms apart: the
    # spot moves 3 mm between samples, interpolated linearly).
    drawn = projector.spot(trajectory.q)
    while True:
        t = base.clock.time
        st = base.state
        pose = st.pose.as_array()
        odom = st.odometry.as_array()
        spot = np.array([np.interp(tau, trajectory.t, drawn[:, j]) for j in range(2)])
        error = float(np.linalg.norm(control_point(pose, follower.L) - spot))
        times.append(t)
        errors.append(error)
        poses.append(pose)
        spots.append(spot)
        if on_step is not None:
            on_step(t, pose, spot, error)
        states.append(follower.state.value)
        straight.append(bool(np.interp(tau, trajectory.t, run) >= 3.0) and tau < end)
        if t + 1e-9 >= next_capture:
            next_capture += period
            if renderer is None:
                c, s = math.cos(pose[2]), math.sin(pose[2])
                rel = np.array([[c, s], [-s, c]]) @ (spot - pose[:2])
                uv, ok = _project_robot_points(T_true, np.array([[rel[0], rel[1], 0.0]]))
                found = bool(ok[0])
            else:
                frame = renderer.render(
                    floor_camera_at(pose),
                    empty,
                    rng=cam_rng,
                    spot=(spot[0], spot[1], 0.0),
                    exposure=FLOOR_CAMERA_EXPOSURE,
                )
                det = detect_laser_spot(frame.image)
                found = det is not None
                uv = np.zeros((1, 2)) if det is None else np.asarray(det.pixel).reshape(1, 2)
            seen = found and cam_rng.random() < DETECTION_PROBABILITY
            noise = cam_rng.normal(0.0, SPOT_PIXEL_SIGMA, 2)
            if seen:
                z = plane.to_robot(uv + noise)[0]
                if np.all(np.isfinite(z)):
                    pending.append((t + CAMERA_LATENCY, t, z, odom.copy()))
        while pending and pending[0][0] <= t + 1e-9:
            _, tc, z, od = pending.popleft()
            follower.observe(tc, z, od)
        _, v_ref, w_ref = trajectory.reference(tau)
        cmd = follower.command(t, odom, Reference(velocity=v_ref, turn_rate=float(w_ref)))
        base.step(float(cmd[0]), float(cmd[1]))
        # The service holds the spot still while the robot reports it lost (stop, search,
        # resume), then carries on drawing.
        if follower.state == TrackState.TRACKING:
            tau = min(tau + CONTROL_DT, end)
        if tau >= end and finished is None:
            finished = t
        if (finished is not None and t >= finished + settle) or t > max_time:
            break
    return FollowRun(
        law=follower.name,
        time=np.asarray(times),
        error=np.asarray(errors),
        pose=np.asarray(poses).reshape(-1, 3),
        spot=np.asarray(spots).reshape(-1, 2),
        state=np.asarray(states),
        straight=np.asarray(straight),
        finished_s=finished,
        lost_events=follower.lost_events,
    )


def make_laws(limits: Limits) -> list[SpotFollower]:
    """Return the three laws with their documented gains."""
    return [
        StateFeedbackLaw(LOOKAHEAD, limits),
        AdaptiveLaw(LOOKAHEAD, limits),
        ProportionalLaw(LOOKAHEAD, limits),
    ]


@dataclass(frozen=True)
class LawMetrics:
    """One law's errors (m): RMS over the run, max, steady (RMS on straight cruising after
    3 s), time to finish (s), spot-lost events."""

    rms_m: float
    max_m: float
    steady_m: float
    finish_s: float | None
    lost_events: int


@dataclass(frozen=True)
class PathFollowingResult:
    """Metrics of `path-following`: path length (m), spot speed (m/s), camera rate (Hz) and
    latency (s), pixel noise (px), the projector's drawing error (max distance of the drawn
    spot from the planned path, m, from the calibrated model's residual error), the floor
    camera's plane errors (normal deg, distance m), where the floor camera's images came from
    (`source`: "rendered" or "projected"), per-law metrics and the error series (`series`:
    law -> {"t": [...], "error_m": [...]}, decimated to 5 Hz for plots)."""

    scenario: str
    seed: int
    path_length_m: float
    spot_speed_mps: float
    camera_hz: float
    latency_s: float
    pixel_sigma: float
    drawing_error_max_m: float
    floor_normal_error_deg: float
    floor_distance_error_m: float
    floor_camera_intrinsics_from: str
    floor_camera_focal_error_pct: float
    floor_camera_rms_px: float
    source: str
    laws: dict[str, LawMetrics]
    series: dict[str, dict[str, list[float]]] = field(repr=False)

    def to_dict(self) -> dict[str, Any]:
        """Return the record as JSON-ready values."""
        return asdict(self)


def start_pose(trajectory: JointTrajectory) -> Pose2D:
    p0 = trajectory.spot[0]
    d = trajectory.spot[min(50, len(trajectory.spot) - 1)] - p0
    yaw = math.atan2(d[1], d[0])
    return Pose2D(p0[0] - LOOKAHEAD * math.cos(yaw), p0[1] - LOOKAHEAD * math.sin(yaw), yaw)


def path_following(
    scene: Scene | None = None,
    seed: int = 0,
    *,
    cameras: list[NetworkCamera] | None = None,
    tour: tuple[tuple[float, float], ...] = TOUR,
    projector: PanTiltProjector | None = None,
    rendered: bool = True,
) -> PathFollowingResult:
    """Run the `path-following` scenario (module docstring) and return its metrics.

    The projector is first calibrated as in `projector-calibration` (with `cameras`, default
    the network calibration's) unless a `projector` model is given; `tour` the waypoints the
    path is planned through. `rendered` (the default): the floor camera's calibration view and
    every frame it takes while following are rendered and detected; otherwise true projections
    plus noise stand in for them.
    """
    scene = scene or default_scene()
    robot = scene.robot
    if robot is None:
        raise InvalidInput(f"scene {scene.name!r} has no robot")
    truth = twin_projector(scene, seed)
    model = projector or projector_calibration(scene, seed, cameras=cameras).model
    path = plan_tour(scene, tour)
    traj = project_path(
        model,
        path,
        SPOT_SPEED,
        spot_acceleration=SPOT_ACCELERATION,
        corner_radius=CORNER_RADIUS,
    )
    drawn = truth.spot(traj.q)
    drawing_error = float(np.max(np.linalg.norm(drawn - traj.spot, axis=1)))
    renderer = Renderer(scene, supersample=1) if rendered else None
    intrinsics = floor_camera_intrinsics(np.random.default_rng([seed, 8]))
    plane = calibrate_floor_camera(np.random.default_rng([seed, 7]), renderer, intrinsics)
    true_plane = np.linalg.inv(floor_camera_mount())
    n_true = true_plane[:3, 2]
    d_true = float(n_true @ true_plane[:3, 3])
    if d_true < 0:
        n_true, d_true = -n_true, -d_true
    normal_err = math.degrees(math.acos(min(1.0, float(plane.normal @ n_true))))
    limits = Limits(robot.limits.max_speed, robot.limits.max_turn_rate)
    start = start_pose(traj)
    laws: dict[str, LawMetrics] = {}
    series: dict[str, dict[str, list[float]]] = {}
    for law in make_laws(limits):
        run = simulate_following(law, traj, truth, plane, start, scene, seed, renderer=renderer)
        laws[law.name] = LawMetrics(
            rms_m=run.rms,
            max_m=float(run.error.max()),
            steady_m=run.steady,
            finish_s=run.finished_s,
            lost_events=run.lost_events,
        )
        step = max(1, round(0.2 / CONTROL_DT))
        series[law.name] = {
            "t": [round(float(x), 3) for x in run.time[::step]],
            "error_m": [round(float(x), 5) for x in run.error[::step]],
        }
    return PathFollowingResult(
        scenario="path-following",
        seed=seed,
        path_length_m=traj.length,
        spot_speed_mps=SPOT_SPEED,
        camera_hz=CAMERA_RATE,
        latency_s=CAMERA_LATENCY,
        pixel_sigma=SPOT_PIXEL_SIGMA,
        drawing_error_max_m=drawing_error,
        floor_normal_error_deg=normal_err,
        floor_distance_error_m=abs(plane.distance - d_true),
        floor_camera_intrinsics_from=intrinsics.source,
        floor_camera_focal_error_pct=focal_error_pct(intrinsics.K, FLOOR_CAMERA_K),
        floor_camera_rms_px=intrinsics.rms,
        source="rendered" if rendered else "projected",
        laws=laws,
        series=series,
    )


@dataclass(frozen=True)
class ProjectorCalibrationResult:
    """Metrics of `projector-calibration`: `spots` commanded and located (by at least two
    cameras), their location error against the twin (`spot_error_rms_m`, per axis RMS), the
    mount's `position_error_m` and `rotation_error_deg` against the twin's true mount, the same
    after moving the estimate by the planar rigid motion that best aligns the calibrated
    cameras' centres with the twin's (`aligned_*`: the network calibration's own frame error
    removed, core.sim.scenarios.multi_target_tracking.frame_alignment; scoring only), the tilt
    offset's error (rad), the calibration's own standard deviations, its RMS floor
    residual (m), `cameras` the calibrated cameras used (their network calibration's
    output, `cameras_from`) and how the spots' pixels were found (`spots_from`). `model`
    (not in to_dict) is the calibrated projector."""

    scenario: str
    seed: int
    spots: int
    spot_error_rms_m: float
    position_error_m: float
    rotation_error_deg: float
    aligned_position_error_m: float
    aligned_rotation_error_deg: float
    tilt_offset_error_rad: float
    position_std_m: float
    rotation_std_deg: float
    rms_m: float
    cameras: tuple[str, ...]
    cameras_from: str
    spots_from: str
    model: PanTiltProjector = field(repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        """Return the record as JSON-ready values (without the model)."""
        d = asdict(self)
        d.pop("model")
        return d


def _true_cameras(scene: Scene, names: list[str]) -> list[NetworkCamera]:
    # The twin's true lenses, for image formation only (physics, not an estimate).
    from core.sim.render import camera_model

    out = []
    for n in names:
        m = camera_model(scene.camera(n))
        out.append(NetworkCamera.from_pose(m.K, m.dist, m.T_world_camera, (m.width, m.height)))
    return out


def _seen(scene: Scene, cam: NetworkCamera, X: Array) -> NDArray[np.bool_]:
    from core.localization.occluders import line_of_sight
    from core.sim.occluders import scene_occluders

    seen: NDArray[np.bool_] = (
        cam.in_view(X) & line_of_sight(cam.center[None], X, scene_occluders(scene))[0]
    )
    return seen


def _spots_projected(
    scene: Scene, names: list[str], spots: Array, rng: np.random.Generator
) -> tuple[Array, NDArray[np.bool_]]:
    """Return (pixels (C, N, 2), visible (C, N)): each spot through each true lens where the
    camera sees it, plus the centroid's pixel noise (CEILING_PIXEL_SIGMA)."""
    X = np.column_stack([spots, np.zeros(len(spots))])
    pixels = np.zeros((len(names), len(X), 2))
    vis = np.zeros((len(names), len(X)), bool)
    for k, cam in enumerate(_true_cameras(scene, names)):
        seen = _seen(scene, cam, X)
        uv = cam.project(X) + rng.normal(0.0, CEILING_PIXEL_SIGMA, (len(X), 2))
        pixels[k, seen] = uv[seen]
        vis[k] = seen
    return pixels, vis


def _spots_in_images(
    scene: Scene, names: list[str], spots: Array, rng: np.random.Generator
) -> tuple[Array, NDArray[np.bool_]]:
    """Return (pixels (C, N, 2), visible (C, N)) of the spots detected in rendered images.

    Each camera's frame of the home (without the robot) is rendered twice with independent
    sensor noise: laser off, and laser on, with the laser's red light added where the spot's
    image falls (a Gaussian blob of LASER_BLOB_SIGMA px: a spot's glare spans a few pixels
    however small the spot; on the bright floor the red channel saturates).
    core.navigation.detect_laser_spot finds it in the on - off difference (the projector
    blinks the laser) or reports it not seen. A spot hidden from a camera adds no light.
    """
    renderer = renderer_for(scene)
    X = np.column_stack([spots, np.zeros(len(spots))])
    people = tuple((float(w.waypoints[0][0]), float(w.waypoints[0][1])) for w in scene.people)
    pixels = np.zeros((len(names), len(X), 2))
    vis = np.zeros((len(names), len(X)), bool)
    for k, (name, cam) in enumerate(zip(names, _true_cameras(scene, names), strict=True)):
        seen = _seen(scene, cam, X)
        if not np.any(seen):
            continue
        base = renderer.render(name, WorldState(0.0, None, people), noise=None).image
        uv = cam.project(X)
        H, W = base.shape[:2]
        r = math.ceil(5 * LASER_BLOB_SIGMA)

        def develop(img: NDArray[np.float32]) -> NDArray[np.uint8]:
            noise = rng.standard_normal(img.shape, dtype=np.float32)
            noisy = img + 2.0 * noise  # sensor noise, 2 grey levels
            return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)

        # One laser-off frame per camera serves every spot (the views do not change).
        off = develop(base.astype(np.float32))

        for i in np.flatnonzero(seen):
            # The blob within 5 sigma of its centre (beyond, its light is below a grey level).
            x0, y0 = max(int(uv[i, 0]) - r, 0), max(int(uv[i, 1]) - r, 0)
            x1, y1 = min(int(uv[i, 0]) + r + 1, W), min(int(uv[i, 1]) + r + 1, H)
            yy, xx = np.mgrid[y0:y1, x0:x1]
            g = np.exp(-((xx - uv[i, 0]) ** 2 + (yy - uv[i, 1]) ** 2) / (2 * LASER_BLOB_SIGMA**2))
            on = base.astype(np.float32)
            on[y0:y1, x0:x1, 2] += 300.0 * g  # red light: the red channel rises (saturates)
            on[y0:y1, x0:x1, 1] += 10.0 * g
            det = detect_laser_spot(develop(on), background=off)
            if det is not None:
                pixels[k, i] = det.pixel
                vis[k, i] = True
    return pixels, vis


# The commanded spots: a grid over the living room, kept off the furniture (the plan says
# where it stands) and inside the projector's reach.
_CALIBRATION_GRID_X = (0.6, 1.3, 2.0, 2.7, 3.4, 4.0)
_CALIBRATION_GRID_Y = (0.8, 1.8, 2.8, 3.8, 4.7)


def projector_calibration(
    scene: Scene | None = None,
    seed: int = 0,
    *,
    cameras: list[NetworkCamera] | None = None,
    cameras_from: str = "marker network calibration (core.sim.scenarios.multi_target_tracking."
    "calibrated_cameras, rendered drive)",
    images: bool = True,
) -> ProjectorCalibrationResult:
    """Run the `projector-calibration` scenario (module docstring) and return its metrics.

    `cameras`: the calibrated ceiling cameras to locate the spots with (default: the scene's
    marker network calibration for `seed`, which renders a drive and takes a while).
    `images`: detect the spots in rendered images (default) or take their true projections
    plus pixel noise.
    """
    scene = scene or default_scene()
    truth = twin_projector(scene, seed)
    nominal = nominal_projector(scene)
    if cameras is None:
        from core.sim.network_cameras import calibrated_cameras

        cameras = list(calibrated_cameras(scene, seed).cameras)
    grid = occupancy_grid(scene, 0.1, PLAN_RESOLUTION)
    gx, gy = np.meshgrid(_CALIBRATION_GRID_X, _CALIBRATION_GRID_Y)
    targets = np.column_stack([gx.ravel(), gy.ravel()])
    ij = np.floor((targets - np.asarray(grid.origin)) / grid.resolution).astype(int)
    targets = targets[grid.free[ij[:, 1], ij[:, 0]]]
    q_cmd = nominal.aim(targets)
    spots = truth.spot(q_cmd)
    rng = np.random.default_rng([seed, 31])
    names = [c.name for c in cameras]
    if images:
        pixels, vis = _spots_in_images(scene, names, spots, rng)
    else:
        pixels, vis = _spots_projected(scene, names, spots, rng)
    located = locate_ml(
        cameras,
        np.nan_to_num(pixels),
        0.0,
        visible=vis,
        pixel_sigma=CEILING_PIXEL_SIGMA,
        min_cameras=2,
    )
    ok = located.valid
    calib = calibrate_projector(nominal, q_cmd[ok], located.xy[ok], estimate_tilt_offset=True)
    pos_err, rot_err = mount_errors(calib.T_world_base, truth.T_world_base)
    from core.sim.network_cameras import frame_alignment

    T2 = frame_alignment(cameras, _true_cameras(scene, names))
    T4 = np.eye(4)
    T4[:2, :2], T4[:2, 3] = T2[:2, :2], T2[:2, 2]
    al_pos, al_rot = mount_errors(T4 @ calib.T_world_base, truth.T_world_base)
    spot_err = located.xy[ok] - spots[ok]
    return ProjectorCalibrationResult(
        scenario="projector-calibration",
        seed=seed,
        spots=int(ok.sum()),
        spot_error_rms_m=float(np.sqrt(np.mean(spot_err**2))),
        position_error_m=pos_err,
        rotation_error_deg=rot_err,
        aligned_position_error_m=al_pos,
        aligned_rotation_error_deg=al_rot,
        tilt_offset_error_rad=float(calib.tilt_offset - (truth.theta[1] - nominal.theta[1])),
        position_std_m=float(np.linalg.norm(calib.position_std)),
        rotation_std_deg=calib.rotation_std_deg,
        rms_m=calib.rms,
        cameras=tuple(names),
        cameras_from=cameras_from,
        spots_from="detected in rendered images" if images else "projected with pixel noise",
        model=calib.model,
    )
