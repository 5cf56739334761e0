"""The robot that reads landmarks with its head camera (spec 04 on the twin): `HeadRobot`.

The head camera and its calibration (core.sim.head_camera): the robot never sees the true
intrinsics, every detection uses the calibrated K and dist.

The robot is a unicycle base with wheel slip and odometry (core.sim.motion) and its head camera
on the pan-tilt unit; frames come every FRAME_DT, rendered from the true pose with the scene's
landmarks (core.sim.render.landmarks, walls and furniture hiding them) and detected with the
calibrated K, dist; every estimate lives in the odometry frame. PBVS (`HeadRobot.read`): the
task function e = (t - t*, theta u) is the landmark's estimated pose against the reading pose
T* (the camera on the mark's horizontal normal at the distance where a module spans
READ_MODULE_PX pixels, looking at its centre); since the base is nonholonomic and the head
keeps the mark in view, the base is driven to the floor pose under T* by the polar
pose-regulation law (Astolfi 1999) and the head's pan and tilt aim at the mark; the estimate is
refreshed every frame, and reading stops when the symbol decodes. The base gets there without
touching furniture the way a robot with a map would: the floor plan (walls, doors, furniture
footprints; a prior, like the installer's plan) is its map (core.sim.floor_routes); a route
planned on it leads to a hand-over point on the mark's estimated normal, APPROACH_M behind the
reading pose, re-planned when the estimate moves by REPLAN_M; from there the polar law drives
straight in. The pose estimate is
the odometry fused by an extended Kalman filter (core.sim.survey_localisation) with the fixes
a robot in this home gets without the twin's truth: a signpost (whose payload carries its
world pose) read within RELOCALISE_M and, when a `CeilingLocaliser` is given, its top marker
located by the ceiling cameras about CEILING_HZ times a second while the base moves.

The landmark scenarios (core.sim.scenarios.landmark_*) and the network's registration by the
signposts (core.sim.network_registration) drive this robot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from core.geometry.poses import planar_pose
from core.geometry.rotations import wrap_angle
from core.landmarks.ambiguity import PoseHypothesis, fuse_hypotheses, is_decided
from core.landmarks.detect import LandmarkDetection, detect_landmarks
from core.landmarks.maps import hypotheses_in_world
from core.sim.floor_routes import PLAN_RESOLUTION, FloorRoutes
from core.sim.head_camera import SIZES, head_camera, reading_standoff, robot_head_pose
from core.sim.intrinsics import NOISE
from core.sim.motion import Pose2D, UnicycleBase
from core.sim.occluders import scene_occluders
from core.sim.render.landmarks import render_scene_landmarks, scene_landmarks
from core.sim.scene import HeadCamera, Scene
from core.sim.survey_localisation import (
    CEILING_MIN_MOVE_M,
    CeilingLocaliser,
    propagate,
    signpost_update,
)

Array = NDArray[np.float64]

FRAME_DT = 0.2  # s: the head camera's frame period while reading and surveying
BASE_DT = 0.05  # s: the base's simulation step
# Polar pose-regulation gains (Astolfi 1999; Siegwart & Nourbakhsh, Introduction to
# Autonomous Mobile Robots, sec. 3.6.2.4): k_rho > 0, k_beta < 0, k_alpha > k_rho for local
# exponential stability, and k_alpha + 5/3 k_beta - 2/pi k_rho > 0 (here 0.27) for strong
# stability (no cusp towards the goal).
K_RHO, K_ALPHA, K_BETA = 0.4, 1.2, -0.4
SEARCH_TILT = 0.05  # rad: the head's tilt while searching (marks at 0.8-1.5 m, head at 1.1 m)
# Tilts of successive search sweeps (rad): level, then up for marks near and above the head.
SEARCH_TILTS = (SEARCH_TILT, -0.3)
MATCH_RADIUS = 0.5  # m: a detection within this of the estimate is the tracked landmark
READ_TIMEOUT_S = 60.0
# The approach: a collision-free route on the floor plan (core.sim.floor_routes) to the
# hand-over point,
# APPROACH_M behind the estimated reading pose on the mark's normal; there the base turns to
# face the mark and the PBVS law drives the last, straight stretch.
APPROACH_M = 0.4  # m: the hand-over point's distance behind the reading pose, at most
REPLAN_M = 0.15  # m: the reading pose's estimate moving more than this re-plans the route
REPLAN_RAD = 0.3  # rad: likewise for its heading
WAYPOINT_M = 0.05  # m: a route point counts as reached within this
TURN_IN_PLACE_RAD = 0.35  # rad: larger heading errors turn the base on the spot
FACE_RAD = 0.05  # rad: heading error at the hand-over point below which PBVS takes over
FOLLOW_GAIN = 2.0  # 1/s: turn rate per radian of heading error while following the route


def polar_command(robot: Array, goal: Array) -> tuple[float, float, float]:
    """Return (v, omega, rho) of the polar pose-regulation law driving a unicycle at robot
    (x, y, yaw) to goal (x, y, yaw): rho, alpha, beta as in Siegwart & Nourbakhsh eq. 3.56
    (the goal frame's origin and heading), reversing when the goal lies behind."""
    dx, dy = goal[0] - robot[0], goal[1] - robot[1]
    rho = float(np.hypot(dx, dy))
    alpha = wrap_angle(np.arctan2(dy, dx) - robot[2])
    direction = 1.0
    if abs(alpha) > np.pi / 2:  # drive backwards: the same law with the heading reversed
        direction = -1.0
        alpha = wrap_angle(alpha + np.pi)
    beta = wrap_angle(goal[2] - robot[2] - alpha)
    v = direction * K_RHO * rho
    omega = K_ALPHA * alpha + K_BETA * beta
    return v, omega, rho


@dataclass
class TrackedLandmark:
    """The tracked landmark in the odometry frame: T_odom_mark, its kind, last seen time, and
    the poses the views so far leave possible (core.landmarks.ambiguity, best first, T the
    first; () for a landmark known from a map, not seen yet)."""

    T: Array
    kind: str
    seen: float
    hypotheses: tuple[PoseHypothesis, ...] = ()

    @property
    def decided(self) -> bool:
        """Return whether the views decide the landmark's pose."""
        return is_decided(self.hypotheses)

    def normal(self) -> Array:
        """Return the normal to approach along (odometry frame): the pose's when decided, else
        the hypotheses' probability-weighted mean (between the two candidates: the line of
        sight, where the next views decide), never one of two undecided normals."""
        if self.decided:
            return self.T[:3, 2]
        return np.asarray(sum(h.probability * h.normal for h in self.hypotheses), dtype=np.float64)


@dataclass
class _Approach:
    """A planned approach: `target` the reading pose (x, y, yaw; odometry frame) it was
    planned for, `offset` (2,; odometry frame) from the estimated reading pose to the free one
    the route leads to (zero unless the estimate fell in an obstacle's margin), `route` (N, 2)
    ending at the hand-over point, in the world (the floor plan's frame: followed through the
    pose estimate of the moment, so a fix made on the way moves the base back onto it), the
    next route point's index, and whether PBVS drives now (`final`)."""

    target: Array
    offset: Array
    route: Array
    index: int = 1
    final: bool = False


@dataclass(frozen=True)
class ReadOutcome:
    """One PBVS reading: whether the symbol was read, when (s after the start), the decoded
    detection (None when unread) with the camera pose it was seen from (odometry frame), the
    frames processed, the final task error |t - t*| (m) and angle (deg) from the estimate."""

    read: bool
    time: float
    detection: LandmarkDetection | None
    T_odom_cam: Array | None
    frames: int
    final_translation_error: float | None
    final_rotation_error_deg: float | None


class HeadRobot:
    """The robot of the landmark scenarios: a unicycle base (true pose, odometry), the head's
    pan-tilt joints (rate limited) and its camera rendered from the true pose; the estimators
    see only the images (through the calibrated K, dist) and the odometry."""

    def __init__(
        self,
        scene: Scene,
        K: Array,
        dist: Array,
        *,
        start: Array | None = None,
        rng: np.random.Generator,
        ceiling: CeilingLocaliser | None = None,
    ) -> None:
        if scene.robot is None or scene.robot.head_camera is None:
            raise InvalidInput("the landmark scenarios need a robot with a head_camera")
        self.scene = scene
        self.robot = scene.robot
        self.head: HeadCamera = scene.robot.head_camera
        self.camera, _ = head_camera(scene)
        self.K, self.dist = K, dist
        s = Pose2D(*(self.robot.start if start is None else start))
        self.base = UnicycleBase(self.robot.limits, self.robot.slip, s, dt=BASE_DT, rng=rng)
        self.rng = rng
        self.pan = 0.0
        self.tilt = 0.0
        self.landmarks = scene_landmarks(scene)
        self.occluders = scene_occluders(scene)
        self.seen: set[int] = set()  # landmarks drawn whole in some frame (for scoring)
        self.collided = False  # the true base touched a wall or furniture (for scoring)
        # The odometry frame in the world: identity at the start (the known start pose),
        # corrected by every fix (a signpost read, relocalise; the ceiling cameras, `ceiling`).
        self.T_world_odom = np.eye(4)
        self.frames = 0
        self.drift_clock = 0.0  # metres driven plus radians turned, on the odometry
        # The pose estimate's covariance (x, y, yaw), now: zero at the known start, grown by
        # the odometry's slip and shrunk by fixes (core.sim.survey_localisation).
        self.P = np.zeros((3, 3))
        # Every correction of T_world_odom: (drift clock, before, after).
        self.fixes: list[tuple[float, Array, Array]] = []
        self.ceiling = ceiling
        self.moved = 0.0  # metres driven since the last ceiling frame
        # The floor plan (walls, doors, furniture footprints) is the robot's map, a prior.
        self.routes = FloorRoutes(scene, self.robot.base_radius)
        self.approach: _Approach | None = None

    @property
    def time(self) -> float:
        """Return the simulated time, s."""
        return self.base.clock.time

    def odom(self) -> Array:
        """Return the odometry pose (x, y, yaw)."""
        return self.base.state.odometry.as_array()

    def estimate(self) -> Array:
        """Return the base's estimated pose (x, y, yaw) in the world: T_world_odom o odometry."""
        o = self.odom()
        W = self.T_world_odom
        p = W @ np.array([o[0], o[1], 0.0, 1.0])
        return np.array([p[0], p[1], wrap_angle(o[2] + float(np.arctan2(W[1, 0], W[0, 0])))])

    def _correct(self, x: Array, P: Array) -> None:
        """Make (x, y, yaw) the base's estimated pose now, with covariance P (a fix)."""
        W = self.T_world_odom
        self.T_world_odom = planar_pose(x) @ np.linalg.inv(planar_pose(self.odom()))
        self.P = P
        self.fixes.append((self.drift_clock, W, self.T_world_odom))

    def T_odom_cam(self) -> Array:
        """Return the head camera's pose in the odometry frame (4, 4)."""
        o = self.odom()
        return planar_pose(o) @ robot_head_pose(self.head, self.pan, self.tilt)

    def aim(self, pan: float, tilt: float, dt: float) -> None:
        """Move the joints towards (pan, tilt) within their limits and rate for dt seconds."""
        step = self.head.max_rate * dt
        lo, hi = self.head.pan_limits
        self.pan += float(np.clip(np.clip(pan, lo, hi) - self.pan, -step, step))
        lo, hi = self.head.tilt_limits
        self.tilt += float(np.clip(np.clip(tilt, lo, hi) - self.tilt, -step, step))

    def look(self) -> list[LandmarkDetection]:
        """Return the detections in the head camera's frame rendered now (true pose)."""
        p = self.base.state.pose
        T_world_cam = planar_pose((p.x, p.y, p.yaw)) @ robot_head_pose(
            self.head, self.pan, self.tilt
        )
        view, idx = render_scene_landmarks(
            self.camera,
            T_world_cam,
            self.landmarks,
            self.occluders,
            noise=NOISE,
            rng=int(self.rng.integers(2**31)),
        )
        self.seen.update(idx)
        self.frames += 1
        up = T_world_cam[:3, :3].T @ np.array([0.0, 0.0, 1.0])  # gravity: a level base
        return detect_landmarks(
            view.image,
            self.K,
            self.dist,
            frame_size=SIZES["object"],
            ring_size=SIZES["signpost"],
            up=up,
        )

    def drive(self, v: float, omega: float, dt: float) -> None:
        """Command the base (v m/s, omega rad/s) for dt seconds; the pose estimate's
        covariance follows the odometry (propagate), and the ceiling cameras fix it about
        CEILING_HZ times a second while the base moves (when `ceiling` is given)."""
        for _ in range(max(1, round(dt / BASE_DT))):
            before = self.base.state.odometry
            self.base.step(v, omega)
            after = self.base.state.odometry
            # The odometry's drift grows with the distance driven and the angle turned (the
            # slip model's variances are linear in both): the clock the survey spreads a
            # relocalisation's correction along.
            step = float(np.hypot(after.x - before.x, after.y - before.y))
            self.drift_clock += step + abs(wrap_angle(after.yaw - before.yaw))
            W = self.T_world_odom
            yaw = before.yaw + float(np.arctan2(W[1, 0], W[0, 0]))
            self.P = propagate(self.P, yaw, before, after, self.robot.slip)
            self.moved += step
            self.collided = self.collided or self.collides()
            c = self.ceiling
            if c is not None and self.moved >= CEILING_MIN_MOVE_M and c.due(self.time):
                self.moved = 0.0
                x = self.estimate()
                fix = c.observe(self.time, self.base.state.pose, x)
                if fix is not None:
                    k = c.update(x, self.P, fix)
                    if k.accepted:
                        self._correct(k.x, k.P)

    def collides(self) -> bool:
        """Return whether the true base overlaps a wall or a piece of furniture (scoring)."""
        p = self.base.state.pose
        return self.clearance(np.array([p.x, p.y])) < 0.0

    def relocalise(self, det: LandmarkDetection, T_odom_cam: Array) -> bool:
        """Correct T_world_odom by the fix a signpost read from T_odom_cam gives (the Kalman
        update of core.sim.survey_localisation.signpost_update, refused as it says); return
        whether it was applied."""
        k = signpost_update(
            det, T_odom_cam, self.T_world_odom, self.estimate(), self.odom(), self.P
        )
        if k is None or not k.accepted:
            return False
        k.x[2] = wrap_angle(float(k.x[2]))
        self._correct(k.x, k.P)
        return True

    def locate(self, det: LandmarkDetection) -> Array:
        """Return T_odom_mark (4, 4) of a detection in the current frame."""
        return self.T_odom_cam() @ det.T_cam_mark

    def track(
        self, det: LandmarkDetection, track: TrackedLandmark | None = None
    ) -> TrackedLandmark:
        """Return the track of a landmark after a detection of it in the current frame: a view
        that decides its pose replaces the estimate (the newest, nearest view is the best);
        one that cannot decide is fused with the track's hypotheses (core.landmarks.
        ambiguity.fuse_hypotheses), both carried until the views together decide."""
        hyps = hypotheses_in_world(det, self.T_odom_cam())
        if track is not None and track.hypotheses and not det.decided:
            hyps = fuse_hypotheses(track.hypotheses, hyps)
        return TrackedLandmark(hyps[0].T, det.kind, self.time, hyps)

    def read(self, track: TrackedLandmark | None, timeout: float = READ_TIMEOUT_S) -> ReadOutcome:
        """Return the outcome of reading a landmark by PBVS (spec 04 sec. 5).

        Without a track the head first sweeps its pan range with the base still
        (SEARCH_TILTS); the first located landmark (the nearest) is tracked, and never
        exchanged for another. Every frame: re-estimate T_odom_mark from the detection
        nearest the track (within MATCH_RADIUS), else keep it (the odometry moves the robot
        under it); the reading pose puts the camera on the mark's horizontal normal at the
        distance where a nominal module spans READ_MODULE_PX pixels (reading_standoff); the
        base follows a route planned on the floor plan to a point on that normal behind it
        (`_plan_approach`, re-planned when the estimate moves), turns to face the mark, and
        the polar law drives it in; the head aims at the mark throughout. Stops when the
        tracked landmark is decoded, or at `timeout`.
        """
        self.approach = None
        t0 = self.time
        frames0 = self.frames
        f = float((self.K[0, 0] + self.K[1, 1]) / 2)
        sweep = self.head.pan_limits[1]
        sweeps = 0
        if track is not None:  # a landmark located earlier: lost only if unseen from now on
            track = TrackedLandmark(track.T, track.kind, self.time, track.hypotheses)
        while self.time - t0 < timeout:
            dets = self.look()
            if track is None:
                located = sorted(dets, key=lambda d: float(np.linalg.norm(d.position)))
                if located:
                    track = self.track(located[0])
                else:
                    # Sweep the pan range end to end (0.4 rad a frame, under half the field),
                    # looking level and then up in turn (a signpost near and above the head).
                    if abs(self.pan - sweep) < 1e-9:
                        sweep = -sweep
                        sweeps += 1
                    self.aim(sweep, SEARCH_TILTS[sweeps % 2], FRAME_DT)
                    self.drive(0.0, 0.0, FRAME_DT)
                    continue
            else:
                best = None
                for d in dets:
                    if d.kind != track.kind:
                        continue
                    e = float(np.linalg.norm(self.locate(d)[:3, 3] - track.T[:3, 3]))
                    if e < MATCH_RADIUS and (best is None or e < best[0]):
                        best = (e, d)
                if best is not None:
                    track = self.track(best[1], track)
                    if best[1].record is not None:
                        err = self._task_error(track, f)
                        seen_from = self.T_odom_cam()
                        self.drive(0.0, 0.0, FRAME_DT)  # brake
                        return ReadOutcome(
                            True, self.time - t0, best[1], seen_from, self.frames - frames0, *err
                        )
            self._servo(track, f)
        final: tuple[float | None, float | None] = (None, None)
        if track is not None:
            final = self._task_error(track, f)
        return ReadOutcome(False, self.time - t0, None, None, self.frames - frames0, *final)

    def _goal(self, track: TrackedLandmark, f: float) -> tuple[Array, Array]:
        """Return the base's reading pose (x, y, yaw) and the camera's (3,) in the odom frame."""
        m = track.T[:3, 3]
        n = track.normal().copy()
        n[2] = 0.0
        nn = float(np.linalg.norm(n))
        if nn < 0.3:  # a mark facing up or down: approach from where the robot stands
            n = np.append(self.odom()[:2] - m[:2], 0.0)
            nn = float(np.linalg.norm(n))
        n /= nn
        d_h = reading_standoff(track.kind, f, float(self.head.position[2] - m[2]))
        cam = m + n * d_h
        cam[2] = self.head.position[2]
        base = m[:2] + n[:2] * (d_h + self.head.position[0])
        return np.array([base[0], base[1], np.arctan2(-n[1], -n[0])]), cam

    def _servo(self, track: TrackedLandmark, f: float) -> None:
        """Run one frame of the approach: the route while it lasts, then the polar law; the
        base's controller runs every BASE_DT on the odometry, the head aims at the mark."""
        goal, _ = self._goal(track, f)
        ap = self.approach
        if ap is None or (
            np.hypot(*(goal[:2] - ap.target[:2])) > REPLAN_M
            or abs(wrap_angle(goal[2] - ap.target[2])) > REPLAN_RAD
        ):
            ap = self.approach = self._plan_approach(goal)
        final = goal.copy()
        if ap is not None:
            final[:2] += ap.offset

        def command() -> tuple[float, float]:
            if ap is not None and not ap.final:
                return self._follow(ap, final[2])
            o = self.odom()
            v, omega, rho = polar_command(o, final)
            if ap is None and rho > 2 * APPROACH_M:
                return 0.0, 0.0  # no route there: the polar law alone would cut through
            if rho < 0.02 and abs(wrap_angle(final[2] - o[2])) < 0.03:
                return 0.0, 0.0  # at the reading pose: wait for a read
            return v, omega

        v, omega = command()
        # Aim the head at the mark from where the base will be after this frame.
        o = self.odom()
        m_r = np.linalg.inv(planar_pose(o)) @ np.append(track.T[:3, 3], 1.0)
        rel = m_r[:3] - np.asarray(self.head.position)
        pan = float(np.arctan2(rel[1], rel[0]) - omega * FRAME_DT)
        tilt = float(np.arctan2(-rel[2], np.hypot(rel[0], rel[1])))
        self.aim(pan, tilt, FRAME_DT)
        for k in range(max(1, round(FRAME_DT / BASE_DT))):
            if k:
                v, omega = command()
            self.drive(v, omega, BASE_DT)

    def plan_route(self, target_world: Array) -> Array | None:
        """Return a collision-free route (N, 2), world (x, y), from the base's estimated
        position (odometry through T_world_odom) to `target_world` on the floor plan
        (FloorRoutes.route), or None when there is none."""
        W = self.T_world_odom
        o = self.odom()
        here = (W @ np.array([o[0], o[1], 0.0, 1.0]))[:2]
        return self.routes.route(here, np.asarray(target_world, dtype=np.float64))

    def _plan_approach(self, goal: Array) -> _Approach | None:
        """Return the approach to the reading pose `goal` (x, y, yaw; odometry frame): the
        free pose nearest it on the mark's normal (the pose itself, unless the estimate put it
        within an obstacle's margin), else the free pose nearest it, the hand-over point up to
        APPROACH_M behind it with a free straight run in, and the route there; None when no
        free pose or route exists (the polar law then drives alone, and only the last
        2 APPROACH_M: from further it would cut through furniture)."""
        W = self.T_world_odom
        out_w = W[:2, :2] @ -np.array([np.cos(goal[2]), np.sin(goal[2])])  # away from the mark
        g0 = (W @ np.array([goal[0], goal[1], 0.0, 1.0]))[:2]
        steps = np.arange(0.0, 0.5 + 1e-9, PLAN_RESOLUTION)
        shift = next((s for s in steps if self.routes.free(g0 + out_w * s)), None)
        if shift is not None:
            g_w = g0 + out_w * shift
        else:
            # Nothing free on the normal (a mark beside a table's corner): the free pose nearest
            # the reading pose; the head still aims at the mark from there.
            near = self.routes.nearest_free(self.routes.grid, g0)
            if near is None:
                return None
            g_w = near
        hand = next(
            (
                g_w + out_w * s
                for s in np.arange(APPROACH_M, -1e-9, -PLAN_RESOLUTION)
                if self.routes.free(g_w + out_w * s) and self.routes.sees(g_w + out_w * s, g_w)
            ),
            g_w,
        )
        route = self.plan_route(hand)
        if route is None:
            return None
        offset = np.linalg.inv(W)[:2, :2] @ (g_w - g0)
        return _Approach(goal.copy(), offset, route)

    def _follow(self, ap: _Approach, heading: float) -> tuple[float, float]:
        """Return (v, omega) following the route on the odometry: turn on the spot towards
        the next route point when off by more than TURN_IN_PLACE_RAD, else drive at it,
        braking to stop there; at the route's end turn to `heading`, then hand over to PBVS."""
        o = self.odom()
        W_inv = np.linalg.inv(self.T_world_odom)
        route = ap.route @ W_inv[:2, :2].T + W_inv[:2, 3]  # on the odometry, as now corrected
        while ap.index < len(route) and np.hypot(*(route[ap.index] - o[:2])) < WAYPOINT_M:
            ap.index += 1
        if ap.index >= len(route):
            err = wrap_angle(heading - o[2])
            if abs(err) < FACE_RAD:
                ap.final = True
                return 0.0, 0.0
            return 0.0, FOLLOW_GAIN * err
        d = route[ap.index] - o[:2]
        err = wrap_angle(float(np.arctan2(d[1], d[0])) - o[2])
        if abs(err) > TURN_IN_PLACE_RAD:
            return 0.0, FOLLOW_GAIN * err
        lim = self.robot.limits
        # Brake in time for the turn at the next point: v <= sqrt(2 (a / 2) d).
        v = min(lim.max_speed, float(np.sqrt(lim.max_acceleration * np.hypot(*d))))
        return v * float(np.cos(err)), FOLLOW_GAIN * err

    def go_to(self, target_world: Array, timeout: float = 120.0) -> bool:
        """Drive the base to the world point (x, y) along a route planned on the floor plan
        (straight when none exists); return whether it arrived within `timeout` s."""
        route = self.plan_route(np.asarray(target_world, dtype=np.float64))
        if route is None:
            route = np.asarray([target_world], dtype=np.float64)
        ap = _Approach(np.zeros(3), np.zeros(2), route, index=0)
        t0 = self.time
        while self.time - t0 < timeout:
            here = self.estimate()[:2]
            while ap.index < len(route) and np.hypot(*(route[ap.index] - here)) < WAYPOINT_M:
                ap.index += 1
            if ap.index >= len(route):
                self.drive(0.0, 0.0, 0.5)
                return True
            o = self.odom()
            self.drive(*self._follow(ap, o[2]), BASE_DT)
        return False

    def _task_error(self, track: TrackedLandmark, f: float) -> tuple[float, float]:
        """Return |t - t*| (m) and theta (deg) of e = (t - t*, theta u) from the estimate:
        T* puts the camera at the reading pose looking at the mark's centre."""
        _, cam = self._goal(track, f)
        T_cam_mark = np.linalg.inv(self.T_odom_cam()) @ track.T
        z = track.T[:3, 3] - cam
        z /= np.linalg.norm(z)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        R_star = np.column_stack([x, np.cross(z, x), z])  # camera at the reading pose, no roll
        T_star = np.eye(4)
        T_star[:3, :3], T_star[:3, 3] = R_star, cam
        T_star_mark = np.linalg.inv(T_star) @ track.T
        dt = float(np.linalg.norm(T_cam_mark[:3, 3] - T_star_mark[:3, 3]))
        dR = T_cam_mark[:3, :3] @ T_star_mark[:3, :3].T
        ang = float(np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1.0, 1.0))))
        return dt, ang

    def clearance(self, p: Array) -> float:
        """Return the gap (m) between the base at p (x, y) and the nearest low wall or furniture."""
        occ = self.occluders
        low = occ.z[:, 0] < self.robot.base_height
        d = np.asarray(p[:2]) - occ.centre
        c, s = np.cos(occ.yaw), np.sin(occ.yaw)
        local = np.abs(np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], 1))
        out = np.linalg.norm(np.maximum(local - occ.half_size, 0.0), axis=1)
        return float(np.min(np.where(low, out, np.inf))) - self.robot.base_radius
