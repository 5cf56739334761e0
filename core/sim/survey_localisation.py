"""The survey robot's pose estimate: its odometry fused with fixes by an extended Kalman filter.

The state is the base's floor pose (x, y, yaw) in the world with its covariance P. Odometry
drives the prediction (`propagate`): each step's increment (forward, lateral, turn) measured
by the wheels, with the slip model's noise (variances linear in the distance driven and the
angle turned; Thrun et al., Probabilistic Robotics, sec. 5.4 and 7.4) and the Jacobian that
turns a heading error into a growing lateral one. Fixes correct it (`kalman_update`): a
signpost read near by (`signpost_update`: the head camera's pose from the rings, read by
core.sim.head_robot), and the robot's top marker located by the home's ceiling cameras
(`CeilingLocaliser`).

The ceiling fixes use the cameras as the home knows them (its installed network calibration,
core.sim.installation.installed_cameras, never the twin's true cameras): about `CEILING_HZ`
times a second while the base moves, the cameras that should see the marker from the
estimated pose (in their view and, on the floor plan, with a clear line of sight) render a
frame, the marker is detected in each (core.localization.detect.detect_marker) and located on
the plane of its height by maximum likelihood over those cameras (core.localization.locate_ml).
The fix is a position only; the filter's cross-covariance (built by the prediction while the
base drives) lets a run of them correct the heading as well. A fix whose innovation fails the
chi-square gate (CEILING_CHI2) is refused: a wrong blob, a marker hidden in part.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from core.errors import IntspaceError, InvalidInput
from core.geometry.poses import planar_pose, pose_from_quaternion
from core.geometry.rotations import wrap_angle
from core.landmarks.detect import LandmarkDetection
from core.landmarks.payload import Signpost
from core.localization import NetworkCamera, line_of_sight, locate_ml
from core.localization.detect import MarkerDetectorConfig, detect_marker
from core.sim._geometry import yaw_matrix
from core.sim.motion import Pose2D, WorldState
from core.sim.occluders import scene_occluders
from core.sim.render import renderer_for
from core.sim.scene import Scene, SlipNoise

Array = NDArray[np.float64]

CEILING_HZ = 1.0  # ceiling frames a second while the base moves
CEILING_MIN_MOVE_M = 0.05  # m driven since the last ceiling frame, at least: a still base skips
# Standard deviation (m, per axis) added to every ceiling fix: the calibrated cameras' own
# error, common to all frames of one camera (its pose and the calibration's frame, whose gauge
# the calibration drive fixes by the robot's start and first leg; the default home's installed
# calibration is turned 0.75 deg from the twin's frame and puts the marker 1-7 cm from where
# the twin has it, depending on the camera), which the pixel noise alone (a few millimetres)
# does not show.
CEILING_FLOOR_M = 0.05
CEILING_CHI2 = 9.21  # chi-square, 2 degrees of freedom, 99 %


def _rot(a: float) -> Array:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s], [s, c]])


def propagate(P: Array, yaw: float, before: Pose2D, after: Pose2D, slip: SlipNoise) -> Array:
    """Return the covariance (3, 3) of the pose estimate (x, y, yaw) after one odometry step
    from `before` to `after` (odometry poses), the estimate's heading being `yaw` (rad).

    The step in the base's frame is (ds, dl, dyaw); the estimate moves by R(yaw) (ds, dl), so
    F = d x' / d x = [[1, 0, -dy_w], [0, 1, dx_w], [0, 0, 1]] with (dx_w, dy_w) = R(yaw)
    (ds, dl); the slip adds Q: variances distance_per_sqrt_m^2 |ds| along, lateral^2 |ds|
    across (rotated to the world) and heading_per_sqrt_m^2 |ds| + heading_per_sqrt_rad^2
    |dyaw| on the heading (core.sim.scene.SlipNoise)."""
    d_odom = np.array([after.x - before.x, after.y - before.y])
    step = _rot(-before.yaw) @ d_odom
    dyaw = wrap_angle(float(after.yaw - before.yaw))
    R = _rot(yaw)
    d_w = R @ step
    F = np.eye(3)
    F[0, 2], F[1, 2] = -d_w[1], d_w[0]
    ds = float(np.hypot(*step))
    Q = np.zeros((3, 3))
    Q[:2, :2] = (
        R @ np.diag([slip.distance_per_sqrt_m**2 * ds, slip.lateral_per_sqrt_m**2 * ds]) @ R.T
    )
    Q[2, 2] = slip.heading_per_sqrt_m**2 * ds + slip.heading_per_sqrt_rad**2 * abs(dyaw)
    return F @ P @ F.T + Q


@dataclass(frozen=True)
class KalmanStep:
    """A Kalman update: the corrected state (n,), its covariance (n, n), the innovation's
    squared Mahalanobis distance and whether it passed the gate (the state and covariance are
    the prior's when it did not)."""

    x: Array
    P: Array
    chi2: float
    accepted: bool


def kalman_update(x: Array, P: Array, nu: Array, H: Array, R: Array, gate: float) -> KalmanStep:
    """Return the Kalman update of (x, P) by the innovation nu = z - h(x) (m,) of a measurement
    with Jacobian H (m, n) and covariance R (m, m), refused when nu^T S^-1 nu > gate with
    S = H P H^T + R (Joseph form for the covariance: it stays symmetric, positive)."""
    S = H @ P @ H.T + R
    chi2 = float(nu @ np.linalg.solve(S, nu))
    if not np.isfinite(chi2) or chi2 > gate:
        return KalmanStep(x, P, chi2, False)
    K = np.linalg.solve(S, H @ P).T
    A = np.eye(len(x)) - K @ H
    return KalmanStep(x + K @ nu, A @ P @ A.T + K @ R @ K.T, chi2, True)


# A signpost's fix (signpost_update): read from nearer than RELOCALISE_M, a correction of the
# estimate within RELOCALISE_GATE, an innovation within the chi-square gate RELOCALISE_CHI2.
RELOCALISE_M = 1.5  # m: a signpost read from nearer than this corrects the odometry
RELOCALISE_GATE = (1.0, 0.35)  # m, rad: larger corrections are outliers
RELOCALISE_CHI2 = 11.34  # chi-square, 3 degrees of freedom, 99 %: the fix's consistency gate


def signpost_update(
    det: LandmarkDetection, T_odom_cam: Array, T_world_odom: Array, x: Array, o: Array, P: Array
) -> KalmanStep | None:
    """Return the Kalman update of the pose estimate x = (x, y, yaw) (covariance P; o the
    odometry pose now, T_world_odom the odometry frame in the world) by a signpost read from
    the camera at T_odom_cam, or None when the read fixes nothing: not a signpost, a pose the
    image cannot decide, read from further than RELOCALISE_M, or a correction larger than
    RELOCALISE_GATE (m, rad).

    The symbol fixes the rotation (its payload carries its world pose): the fix T_world_cam =
    T_world_mark T_cam_mark^-1, kept planar (camera x, y and the odometry frame's yaw), with
    its covariance from the detection's (first order), is fused with the estimate (the state
    is the base's pose now, the camera a point fixed on it, P the estimate's covariance grown
    by the odometry's slip since the last fix). A ring's yaw is its weakest direction
    (degrees), so the estimate keeps weight there. The step is not `accepted` when its
    innovation fails the chi-square test (RELOCALISE_CHI2): an outlier."""
    rec = det.record
    if not isinstance(rec, Signpost) or not det.orientation_known or not det.decided:
        return None  # (a pose the image cannot decide fixes nothing)
    if float(np.linalg.norm(det.position)) > RELOCALISE_M:
        return None
    T_world_mark = pose_from_quaternion(rec.pose[:3], rec.pose[3:])
    T_wc = T_world_mark @ np.linalg.inv(det.T_cam_mark)
    M = T_wc @ np.linalg.inv(T_odom_cam)
    new = planar_pose((M[0, 3], M[1, 3], float(np.arctan2(M[1, 0], M[0, 0]))))
    D = new @ np.linalg.inv(T_world_odom)
    at = D @ np.append(T_odom_cam[:3, 3], 1.0) - np.append(T_odom_cam[:3, 3], 1.0)
    dist_gate, angle_gate = RELOCALISE_GATE
    if np.hypot(at[0], at[1]) > dist_gate or abs(np.arctan2(D[1, 0], D[0, 0])) > angle_gate:
        return None
    # The fix's covariance: camera position c = -R^T t in the mark frame and the camera's
    # yaw, to first order in (rotation vector, translation) of T_cam_mark.
    R_cm, t = det.T_cam_mark[:3, :3], det.T_cam_mark[:3, 3]
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    J = np.zeros((3, 6))
    J[:2] = (T_world_mark[:3, :3] @ np.hstack([-R_cm.T @ tx, -R_cm.T]))[:2]
    J[2, :3] = -T_wc[2, :3]
    R_fix = J @ det.cov @ J.T
    # The measurement model: the camera where the fix saw it, c = (x, y) + R(phi) (c_odom
    # - o), phi = yaw - yaw_odom the odometry frame's heading (the base's estimated pose
    # x = (x, y, yaw) now, o its odometry now).
    phi = wrap_angle(float(x[2] - o[2]))
    r_w = yaw_matrix(phi)[:2, :2] @ (T_odom_cam[:2, 3] - o[:2])
    H = np.array([[1.0, 0.0, -r_w[1]], [0.0, 1.0, r_w[0]], [0.0, 0.0, 1.0]])
    fix = np.array([T_wc[0, 3], T_wc[1, 3], np.arctan2(M[1, 0], M[0, 0])])
    nu = fix - np.array([x[0] + r_w[0], x[1] + r_w[1], phi])
    nu[2] = wrap_angle(float(nu[2]))
    # A fix that disagrees with the estimate beyond their covariances (the rings' other
    # pose, whose yaw the wide RELOCALISE_GATE still lets through) is an outlier.
    return kalman_update(x, P, nu, H, R_fix, RELOCALISE_CHI2)


@dataclass(frozen=True)
class MarkerFix:
    """The robot's top marker located by the ceiling cameras at `time` (s): its floor position
    xy (2,) in the world (m), the covariance (2, 2) m^2 (the pixel noise's, plus
    CEILING_FLOOR_M^2 per axis), and the cameras that saw it."""

    time: float
    xy: Array
    cov: Array
    cameras: tuple[str, ...]


class CeilingLocaliser:
    """Locates the robot's top marker in rendered ceiling-camera frames (module docstring).

    scene: the twin (its renderer draws what the cameras see; the robot and its marker's
    colour, height and offset are the robot's own specification); cameras: the calibrated
    ceiling cameras, by the names of the scene's cameras; rate_hz: frames a second, at most;
    rng: the sensor noise's seed. Counts `frames` rendered, `fixes` made, `refused` by the
    filter's gate (`refuse`)."""

    def __init__(
        self,
        scene: Scene,
        cameras: Sequence[NetworkCamera],
        *,
        rate_hz: float = CEILING_HZ,
        rng: np.random.Generator,
    ) -> None:
        if scene.robot is None or scene.robot.marker is None:
            raise InvalidInput("ceiling fixes need a robot with a top marker")
        if not (np.isfinite(rate_hz) and rate_hz > 0):
            raise InvalidInput(f"rate_hz must be a positive number, got {rate_hz}")
        names = {c.name for c in scene.cameras}
        unknown = [c.name for c in cameras if c.name not in names]
        if unknown:
            raise InvalidInput(f"cameras {unknown} are not cameras of the scene {sorted(names)}")
        self.scene = scene
        self.cameras = list(cameras)
        self.period = 1.0 / float(rate_hz)
        self.rng = rng
        self.renderer = renderer_for(scene)
        self.occluders = scene_occluders(scene)
        marker = scene.robot.marker
        self.config = MarkerDetectorConfig(colour=marker.colour)
        self.height = float(marker.height)
        self.offset = np.asarray(marker.offset, dtype=np.float64)
        self.away = tuple((1e4, 1e4) for _ in scene.people)  # nobody walks the surveyed home
        self.centres = np.array([c.center for c in self.cameras]).reshape(-1, 3)
        self.last = -np.inf
        self.frames = 0
        self.fixes = 0
        self.refused = 0

    def due(self, t: float) -> bool:
        """Return whether a frame is due at time t (s)."""
        return t - self.last >= self.period - 1e-9

    def marker_xy(self, pose: Array) -> Array:
        """Return the marker's floor position (2,) for a base pose (x, y, yaw)."""
        return pose[:2] + _rot(float(pose[2])) @ self.offset

    def observe(self, t: float, true_pose: Pose2D, estimate: Array) -> MarkerFix | None:
        """Return the marker located in the frames rendered now (the twin at `true_pose`, as
        the cameras would see it) by the cameras that should see it from the `estimate`
        (x, y, yaw), or None when none sees it."""
        self.last = t
        if not self.cameras:
            return None
        X = np.append(self.marker_xy(estimate), self.height)[None]
        seen = np.array([c.in_view(X)[0] for c in self.cameras])
        if seen.any():
            seen[seen] = line_of_sight(self.centres[seen], X, self.occluders)[:, 0]
        state = WorldState(t, true_pose, self.away)
        cams, pixels, covs = [], [], []
        for k in np.flatnonzero(seen):
            cam = self.cameras[k]
            image = self.renderer.render(cam.name, state, rng=self.rng).image
            self.frames += 1
            found = detect_marker(image, self.config, background=self.renderer.empty(cam.name))
            if found is not None:
                cams.append(cam)
                pixels.append(found.pixel)
                covs.append(found.cov)
        if not cams:
            return None
        try:
            est = locate_ml(cams, np.array(pixels), self.height, pixel_cov=np.array(covs))
        except IntspaceError:  # a ray that misses the plane: no fix from this frame
            return None
        if not bool(est.valid):
            return None
        cov = np.asarray(est.cov, dtype=np.float64) + np.eye(2) * CEILING_FLOOR_M**2
        return MarkerFix(t, np.asarray(est.xy, dtype=np.float64), cov, tuple(c.name for c in cams))

    def update(self, x: Array, P: Array, fix: MarkerFix) -> KalmanStep:
        """Return the Kalman update of the base pose (x, y, yaw) and covariance P by a marker
        fix: h(x) = (x, y) + R(yaw) offset, H = [I, R'(yaw) offset]."""
        R = _rot(float(x[2]))
        H = np.zeros((2, 3))
        H[:, :2] = np.eye(2)
        H[:, 2] = R @ np.array([-self.offset[1], self.offset[0]])
        step = kalman_update(x, P, fix.xy - self.marker_xy(x), H, fix.cov, CEILING_CHI2)
        if step.accepted:
            self.fixes += 1
        else:
            self.refused += 1
        return step

    def summary(self) -> dict[str, float | int]:
        """Return the frames rendered, fixes applied and fixes refused, and the rate."""
        return {
            "rate_hz": 1.0 / self.period,
            "frames": self.frames,
            "fixes": self.fixes,
            "refused": self.refused,
            "cameras": len(self.cameras),
        }
