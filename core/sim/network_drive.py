"""The marker calibration drive in the twin: what an installer and the robot do to calibrate
the network.

1. Each camera's own calibration from a chessboard shown to it
   (core.sim.board_session.show_chessboard).
2. The robot's drive through a programme of stops, steered by its odometry
   (core.sim.calibration_drive); the calibration is told the odometry between the stops.
3. Every camera's observations of the robot's marker (and of its raised mast's) at every stop
   (core.sim.marker_observations.observe_marker); `drive_and_observe` drives and observes,
   with a second pass for the cameras that saw the marker too rarely.
4. `drive_marker_calibration`: 1-3 and core.calibration.network.calibrate_network_marker.

The true cameras and the true stops are returned for scoring only
(core.sim.network_errors, `bound_for`: core.calibration.network.marker_network_bound).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from core.calibration.network import (
    CameraBound,
    NetworkCalibration,
    calibrate_network_marker,
    marker_network_bound,
)
from core.errors import InvalidInput
from core.sim.board_session import BoardSession, show_chessboard
from core.sim.calibration_drive import Drive, Driver, plan_stops, revisit_stops
from core.sim.marker_observations import MarkerObservations, observe_marker, robot_markers
from core.sim.render import CameraModel, Renderer, SensorNoise
from core.sim.scene import Robot, Scene, raise_mast

Array = NDArray[np.float64]

_DEFAULT_NOISE = SensorNoise()


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
