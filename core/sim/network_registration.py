"""The twin's signpost tour: the calibrated camera network registered to the world (02 §1).

After its marker drive the robot visits the signposts the home's map declares (their payloads
carry their poses in the world) and reads each by PBVS with its head camera, as the landmark
survey does (core.sim.head_robot.HeadRobot, its head camera calibrated by Zhang). Where a
signpost is read the robot stands still and two things locate its top marker:

* the world, through the read: T_world_cam = T_world_mark T_cam_mark^-1 (the payload's pose,
  the detection's), then the head's kinematics (pan, tilt) and the marker's place on the robot;
  covariance from the detection's 6 x 6 to first order: with m the marker in the head camera's
  frame, the marker in the mark's frame is q = R^T (m - t), so dq = R^T [m - t]x dphi - R^T dt;
* the network, through the ceiling frames of that moment: each calibrated camera that finds the
  marker back-projects it onto the plane at the marker's height, with its pixel covariance plus
  CAMERA_ERROR_M of calibration error on the floor, and the cameras are fused by information.

core.calibration.network.register_planar turns the pairs into the floor rigid motion from the
network's frame to the world. The odometry between signposts is corrected by each read (the
survey's relocalisation), only so that the robot finds the next one; the registration itself
uses no odometry. The twin's truth renders the frames and nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from core.calibration.network import (
    NetworkCalibration,
    PlanarRegistration,
    register_planar,
    registered,
)
from core.errors import DegenerateConfiguration, InvalidInput
from core.geometry.poses import planar_pose, pose_from_quaternion
from core.landmarks.payload import PayloadError, Signpost, decode_payload
from core.localization import NetworkCamera
from core.localization.detect import MarkerDetectorConfig, detect_marker
from core.localization.ground import locate_monocular
from core.sim.head_camera import (
    calibrate_scene_head_camera,
)
from core.sim.head_robot import (
    HeadRobot,
    TrackedLandmark,
)
from core.sim.motion import world_state
from core.sim.render import Renderer, camera_model
from core.sim.render.landmarks import scene_landmarks
from core.sim.scene import Scene

Array = NDArray[np.float64]

# The network's own geometry places a floor point within about this of where the network's
# other cameras place it (the marker calibration's bound inside its frame: 0.7-1.1 cm and
# 0.07-0.24 deg at 3-5 m per camera on the default home; 0.3-0.9 cm and 0.06-0.26 deg with a
# mast marker).
CAMERA_ERROR_M = 0.015
READ_TIMEOUT_S = 45.0
HEAD_CALIBRATION_VIEWS = 12


@dataclass(frozen=True)
class SignpostSighting:
    """The robot's marker where it read signpost `signpost` (its id): in the world from the
    read (`world_xy`, `world_cov`), in the network's frame from the ceiling (`network_xy`,
    `network_cov`, by `cameras` ceiling cameras), at simulated time `t` s."""

    signpost: int
    world_xy: Array
    world_cov: Array
    network_xy: Array
    network_cov: Array
    cameras: int
    t: float


@dataclass(frozen=True)
class SignpostRegistration:
    """The signpost tour's outcome: `registration` (None when fewer than two signposts could
    be used, with `reason`), the `sightings` used, the signposts the map declares
    (`declared`), those read (`read`), the tour's simulated `duration_s` and head frames."""

    registration: PlanarRegistration | None
    sightings: tuple[SignpostSighting, ...]
    declared: int
    read: int
    duration_s: float
    frames: int
    reason: str = ""


def declared_signposts(scene: Scene) -> list[tuple[int, Array]]:
    """Return the (id, T_world_mark (4, 4)) of every signpost the home's map declares: the
    payloads printed on them (a landmark whose payload does not decode is no signpost)."""
    out = []
    for lm in scene_landmarks(scene):
        try:
            rec = decode_payload(lm.text)
        except PayloadError:
            continue
        if isinstance(rec, Signpost):
            out.append((rec.id, _mark_pose(rec)))
    return out


def _mark_pose(rec: Signpost) -> Array:
    """Return T_world_mark (4, 4) of the pose a signpost's payload carries."""
    return pose_from_quaternion(rec.pose[:3], rec.pose[3:])


def marker_from_read(
    robot: HeadRobot, rec: Signpost, T_cam_mark: Array, cov: Array, T_odom_cam: Array
) -> tuple[Array, Array]:
    """Return the robot's top marker (x, y) in the world now and its 2 x 2 covariance from a
    signpost read from the head camera pose `T_odom_cam` (odometry frame; the base may have
    moved a little since, braking: the odometry carries the marker over that move). Module
    docstring for the covariance."""
    assert robot.robot.marker is not None
    T_world_mark = _mark_pose(rec)
    mk = robot.robot.marker
    m_robot = np.array([mk.offset[0], mk.offset[1], mk.height, 1.0])
    T_odom_robot = planar_pose(robot.odom())
    m = (np.linalg.inv(T_odom_cam) @ T_odom_robot @ m_robot)[:3]  # in the reading camera
    R, t = T_cam_mark[:3, :3], T_cam_mark[:3, 3]
    q = R.T @ (m - t)
    d = m - t
    dx = np.array([[0.0, -d[2], d[1]], [d[2], 0.0, -d[0]], [-d[1], d[0], 0.0]])
    J = T_world_mark[:3, :3] @ np.hstack([R.T @ dx, -R.T])
    world = (T_world_mark @ np.append(q, 1.0))[:2]
    C = (J @ cov @ J.T)[:2, :2]
    return world, 0.5 * (C + C.T)


def marker_from_ceiling(
    renderer: Renderer,
    cameras: list[NetworkCamera],
    robot: HeadRobot,
    config: MarkerDetectorConfig,
) -> tuple[Array, Array, int] | None:
    """Return the marker's (x, y) in the network's frame, its covariance and how many ceiling
    cameras found it, from the frames rendered now; None when none did."""
    scene = robot.scene
    assert scene.robot is not None and scene.robot.marker is not None
    height = scene.robot.marker.height
    state = world_state(scene, robot.time, robot.base.state.pose)
    info = np.zeros((2, 2))
    vec = np.zeros(2)
    n = 0
    for cam in cameras:
        frame = renderer.render(cam.name, state, rng=robot.rng)
        found = detect_marker(frame.image, config, background=renderer.empty(cam.name))
        if found is None:
            continue
        est = locate_monocular(cam, found.pixel[None], height, pixel_cov=found.cov[None])
        if not est.valid[0]:
            continue
        C = est.cov[0] + CAMERA_ERROR_M**2 * np.eye(2)
        W = np.linalg.inv(C)
        info += W
        vec += W @ est.xy[0]
        n += 1
    if n == 0:
        return None
    cov = np.asarray(np.linalg.inv(info), dtype=np.float64)
    return cov @ vec, cov, n


def signpost_registration(
    scene: Scene,
    cameras: list[NetworkCamera],
    seed: int = 0,
    *,
    renderer: Renderer | None = None,
) -> SignpostRegistration:
    """Tour the declared signposts from the robot's start pose, nearest first (module
    docstring), and register the network of `cameras` (calibrated, in the frame of its marker
    drive) to the world. Raises InvalidInput for a scene without a robot, marker or head
    camera."""
    if scene.robot is None or scene.robot.marker is None or scene.robot.head_camera is None:
        raise InvalidInput("the signpost tour needs a robot with a top marker and a head camera")
    declared = declared_signposts(scene)
    renderer = renderer or Renderer(scene)
    names = {c.name for c in scene.cameras}
    ceiling = [c for c in cameras if c.name in names]
    rng = np.random.default_rng([seed, 41])
    K, dist, _ = calibrate_scene_head_camera(scene, rng, HEAD_CALIBRATION_VIEWS)
    robot = HeadRobot(scene, K, dist, rng=rng)
    config = MarkerDetectorConfig(colour=scene.robot.marker.colour)
    sightings: list[SignpostSighting] = []
    read = 0
    used: set[int] = set()
    left = list(declared)
    while left:
        here = robot.estimate()[:2]
        left.sort(key=lambda item: float(np.hypot(*(item[1][:2, 3] - here))))
        _, T_world_mark = left.pop(0)
        T_odom_mark = np.linalg.inv(robot.T_world_odom) @ T_world_mark
        out = robot.read(TrackedLandmark(T_odom_mark, "signpost", robot.time), READ_TIMEOUT_S)
        det = out.detection
        if not out.read or det is None or out.T_odom_cam is None:
            continue
        rec = det.record
        if not isinstance(rec, Signpost) or rec.id in used:
            continue  # another signpost than the one aimed at may be read: once each
        used.add(rec.id)
        left = [item for item in left if item[0] != rec.id]
        read += 1
        world = marker_from_read(robot, rec, det.T_cam_mark, det.cov, out.T_odom_cam)
        seen = marker_from_ceiling(renderer, ceiling, robot, config)
        # The read also corrects the odometry, so that the robot finds the next signpost.
        robot.relocalise(det, out.T_odom_cam)
        if seen is None:
            continue
        sightings.append(
            SignpostSighting(rec.id, world[0], world[1], seen[0], seen[1], seen[2], robot.time)
        )
    reg, reason = None, ""
    if len(sightings) >= 2:
        try:
            reg = register_planar(
                [s.network_xy for s in sightings],
                [s.network_cov for s in sightings],
                [s.world_xy for s in sightings],
                [s.world_cov for s in sightings],
            )
        except DegenerateConfiguration as exc:
            reason = str(exc)
    else:
        reason = f"{len(sightings)} signpost(s) read where a ceiling camera saw the robot"
    return SignpostRegistration(
        reg, tuple(sightings), len(declared), read, robot.time, robot.frames, reason
    )


def can_register(scene: Scene) -> bool:
    """Return whether the scene's robot can tour signposts (a top marker and a head camera)
    and its home declares at least two."""
    robot = scene.robot
    if robot is None or robot.marker is None or robot.head_camera is None:
        return False
    return len(declared_signposts(scene)) >= 2


def register_network(
    calibration: NetworkCalibration,
    scene: Scene,
    seed: int = 0,
    *,
    renderer: Renderer | None = None,
) -> tuple[NetworkCalibration, SignpostRegistration]:
    """Return `calibration` (a marker drive's, in its start pose's frame) registered to the
    world by the signpost tour, and the tour; the calibration unchanged when the tour could
    not register it (`SignpostRegistration.reason`)."""
    sizes = {c.name: (camera_model(c).width, camera_model(c).height) for c in scene.cameras}
    cams = [
        NetworkCamera.from_pose(c.K, c.dist, c.T_world_camera, sizes[c.name], c.name)
        for c in calibration.cameras
        if c.name in sizes
    ]
    tour = signpost_registration(scene, cams, seed, renderer=renderer)
    if tour.registration is None:
        return calibration, tour
    return registered(calibration, tour.registration), tour


__all__ = [
    "CAMERA_ERROR_M",
    "SignpostRegistration",
    "SignpostSighting",
    "can_register",
    "declared_signposts",
    "register_network",
    "signpost_registration",
]
