"""The robot following the projected spot in the twin, in closed loop (spec 03).

The path the spot draws is planned on the floor plan inflated by the robot's radius plus
`PLAN_MARGIN` (`PLAN_RESOLUTION` cells) and drawn at `SPOT_SPEED` within `SPOT_ACCELERATION`,
its corners rounded by `CORNER_RADIUS`. `simulate_following` runs one law (`make_laws`: the
state-feedback, adaptive and proportional laws with their gains) from `start_pose`: the floor
camera (core.sim.floor_camera) takes frames at `CAMERA_RATE` rendered from the robot's true
pose, core.navigation.detect_laser_spot finds the spot in each (no laser-off frame: the camera
moves), which is then given SPOT_PIXEL_SIGMA of extra pixel noise, dropped at random
(DETECTION_PROBABILITY: glints and motion blur the renderer does not draw), back-projected on
the floor plane from the camera's own one-view calibration and handed to the controller
`CAMERA_LATENCY` later. Without a renderer (unit tests) the spot's true projection stands in for
the detection. Errors are the distance between the robot's control point and the true spot,
against the twin.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from core.calibration.onboard import FloorPlane
from core.errors import InvalidInput
from core.navigation import detect_laser_spot
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
from core.projector import JointTrajectory, PanTiltProjector
from core.sim.floor_camera import (
    FLOOR_CAMERA_EXPOSURE,
    floor_camera_at,
    floor_camera_mount,
    project_robot_points,
)
from core.sim.motion import Pose2D, UnicycleBase, WorldState
from core.sim.render import Renderer
from core.sim.scene import Scene

Array = NDArray[np.float64]

# on_step(t, pose, spot, error) of simulate_following: s, (3,) x y theta, (2,) x y, m.
StepCallback = Callable[[float, Array, Array, float], None]

# Sub-pixel spot centroid noise (px), a conservative bound: the detector's tests measure
# ~0.02 px on clean rendered blobs (tests/core/navigation/test_spot_detection.py).
SPOT_PIXEL_SIGMA = 0.3
CAMERA_RATE = 15.0  # Hz
CAMERA_LATENCY = 0.1  # s from capture to the robot's controller
DETECTION_PROBABILITY = 0.98  # per frame with the spot in view (glints, motion blur)
CONTROL_DT = 0.02  # s, the controller's and the simulated base's step
LOOKAHEAD = 0.6  # m, the control point P ahead of the axle (in the floor camera's view)

SPOT_SPEED = 0.3  # m/s, cruising
# m/s^2, the spot's tangential and lateral acceleration bound (a gentle spot is one a
# follower can keep under: the adaptive law's error on a curve is about this over Gamma).
SPOT_ACCELERATION = 0.05
CORNER_RADIUS = 0.5  # m, the fillets rounding the planned path's corners
# The path is planned on a grid of PLAN_RESOLUTION m cells, PLAN_MARGIN m beyond the robot's
# radius from walls and furniture.
PLAN_RESOLUTION = 0.05
PLAN_MARGIN = 0.05


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
                uv, ok = project_robot_points(T_true, np.array([[rel[0], rel[1], 0.0]]))
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


def start_pose(trajectory: JointTrajectory) -> Pose2D:
    p0 = trajectory.spot[0]
    d = trajectory.spot[min(50, len(trajectory.spot) - 1)] - p0
    yaw = math.atan2(d[1], d[0])
    return Pose2D(p0[0] - LOOKAHEAD * math.cos(yaw), p0[1] - LOOKAHEAD * math.sin(yaw), yaw)
