"""The running digital twin: the default home simulated in a background thread.

The robot patrols and the scene's people walk; at `rate_hz` every ceiling camera's frame is
rendered, the robot's marker and the people are detected in the images, located on the floor
with the registry's current calibration of the cameras (core.localization, ML on the plane) and
tracked (core.localization.tracking: constant-velocity Kalman filters, the robot's track
labelled) and handed to the live targets store. The latest frame of each camera and its
detections are kept for the API; the live 3D scene gets the agents, tracks and images at a
throttled rate.

The twin's scene is also the calibration object of the "network" calibration runs.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from core.errors import InvalidInput
from core.localization import NetworkCamera, locate_ml
from core.localization.detect import MarkerDetectorConfig, PersonDetector, detect_marker
from core.localization.tracking import FloorTracker, TrackerConfig
from core.sim import Scene, SensorNoise, UnicycleBase, WorldState, world_state
from core.sim.motion import Patrol
from core.sim.render import camera_model, renderer_for
from server.db.models import Camera, Robot, Room, Space

if TYPE_CHECKING:
    from server.services.scene_sync import SceneSync
    from server.services.targets import LiveTargets

log = logging.getLogger(__name__)

CAMERA_NOMINAL = "nominal"
# Physics step of the robot base (s); the twin steps it as often as a frame period needs.
_BASE_DT = 0.05
# People detections from different cameras closer than this (m) are one person.
_PERSON_GATE_M = 0.8
# Pushes to the 3D scene (agents, tracks) and camera images, at most this often (Hz).
_SCENE_HZ = 5.0
# Acceleration spectral density of the tracker (m^2/s^3): walking people and a robot that
# turns at its waypoints.
_TRACKER_Q = 0.5
_IMAGE_HZ = 1.0


# --------------------------------------------------------------------------------------------
# Registry bootstrap


def bootstrap_space(session: Session, scene: Scene) -> tuple[int, dict[str, int]]:
    """Create the space, rooms, cameras (installed nominal calibration, status "nominal") and
    robot of `scene` when the registry has no space yet; return (space id, camera name -> id)
    of the space holding the scene's cameras."""
    space = session.scalar(select(Space).order_by(Space.id).limit(1))
    if space is None:
        space = Space(name=scene.name, description="the digital twin's home")
        session.add(space)
        session.flush()
        for room in scene.rooms:
            polygon = [[float(x), float(y)] for x, y in room.polygon]
            session.add(Room(space_id=space.id, name=room.name, polygon=polygon))
        for spec in scene.cameras:
            model = camera_model(spec)
            session.add(
                Camera(
                    space_id=space.id,
                    name=spec.name,
                    width=model.width,
                    height=model.height,
                    K=model.K.tolist(),
                    dist=model.dist.tolist(),
                    T_world_camera=model.T_world_camera.tolist(),
                    status=CAMERA_NOMINAL,
                )
            )
        if scene.robot is not None:
            session.add(
                Robot(
                    space_id=space.id,
                    name=scene.robot.name,
                    kinematic_model={
                        "model": "unicycle",
                        "base_radius": scene.robot.base_radius,
                        "base_height": scene.robot.base_height,
                        "limits": scene.robot.limits.model_dump(),
                    },
                )
            )
        session.commit()
    names = [c.name for c in scene.cameras]
    rows = session.execute(
        select(Camera.id, Camera.name).where(Camera.space_id == space.id, Camera.name.in_(names))
    ).all()
    return space.id, {name: id for id, name in rows}


def registry_cameras(
    session: Session, ids: list[int]
) -> tuple[dict[int, NetworkCamera], dict[int, str]]:
    """Return the NetworkCamera of each camera of `ids` that has K and a pose, and the reason
    for each one that cannot be used."""
    usable: dict[int, NetworkCamera] = {}
    refused: dict[int, str] = {}
    found = {c.id: c for c in session.scalars(select(Camera).where(Camera.id.in_(ids)))}
    for camera_id in ids:
        camera = found.get(camera_id)
        if camera is None:
            refused[camera_id] = f"no camera with id {camera_id}"
        elif camera.K is None:
            refused[camera_id] = f"camera {camera_id} ({camera.name}) has no intrinsics K"
        elif camera.T_world_camera is None:
            refused[camera_id] = f"camera {camera_id} ({camera.name}) has no pose T_world_camera"
        else:
            usable[camera_id] = NetworkCamera.from_pose(
                camera.K,
                camera.dist,
                camera.T_world_camera,
                (camera.width, camera.height),
                camera.name,
            )
    return usable, refused


# --------------------------------------------------------------------------------------------
# Network calibration drive


def network_calibration_drive(
    scene: Scene, seed: int, *, spacing: float = 0.3, placement_sigma: float = 0.002
) -> dict[str, Any]:
    """Return the result of calibrating the scene's cameras by driving the robot's marker over
    a grid of stops (the twin's network-calibration scenario, core.sim.scenarios), with each
    calibrated camera's K, dist, T_world_camera, std, rms and its errors against the twin."""
    from core.sim.scenarios import calibration_errors, drive_marker_calibration

    if scene.robot is None or scene.robot.marker is None:
        raise InvalidInput("the twin's robot carries no marker to calibrate the network with")
    # Shared with the running twin: the static layer of each camera is built once.
    drive = drive_marker_calibration(
        scene,
        seed,
        spacing=spacing,
        placement_sigma=placement_sigma,
        noise=SensorNoise(),
        renderer=renderer_for(scene),
    )
    net, cams = drive.calibration, drive.true_cameras
    cameras = []
    for cal in net.cameras:
        true = next(cm for cm in cams if cm.name == cal.name)
        err = calibration_errors(cal, true)
        cameras.append(
            {
                "name": cal.name,
                "K": cal.K.tolist(),
                "dist": cal.dist.tolist(),
                "T_world_camera": cal.T_world_camera.tolist(),
                "std": {
                    "f_px": float(cal.std[0]),
                    "rvec_rad": cal.std[1:4].tolist(),
                    "t_m": cal.std[4:7].tolist(),
                },
                "rms": cal.rms,
                "poses_seen": cal.poses_seen,
                "errors": {
                    "focal_pct": err.focal_pct,
                    "position_m": err.position_m,
                    "rotation_deg": err.rotation_deg,
                },
                "image_size": [true.width, true.height],
            }
        )
    return {
        "kind": "network",
        "target": "marker",
        "poses": drive.poses,
        "detections": int(drive.seen.sum()),
        "rms": float(net.rms),
        "cameras": cameras,
        "rejected": [
            {"name": r.name, "reason": r.reason, "poses_seen": r.poses_seen} for r in net.rejected
        ],
    }


# --------------------------------------------------------------------------------------------
# The running twin


@dataclass
class CameraFrame:
    """The latest frame of a twin camera and what was detected in it."""

    camera_id: int
    name: str
    t: float
    image: np.ndarray
    detections: list[dict[str, Any]] = field(default_factory=list)


class Twin:
    """The simulated home running in a background thread (never on the event loop)."""

    def __init__(
        self,
        scene: Scene,
        factory: sessionmaker[Session],
        targets: LiveTargets,
        scene_sync: SceneSync | None = None,
        *,
        rate_hz: float = 5.0,
        seed: int = 0,
    ) -> None:
        self.scene = scene
        self.space_id: int | None = None
        self.camera_ids: dict[str, int] = {}
        self._factory = factory
        self._targets = targets
        self._scene_sync = scene_sync
        self._seed = seed
        self.rate_hz = float(rate_hz)
        self._renderer = renderer_for(scene)
        self._marker_cfg = (
            MarkerDetectorConfig(colour=scene.robot.marker.colour)
            if scene.robot is not None and scene.robot.marker is not None
            else None
        )
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._paused = threading.Event()
        self._thread: threading.Thread | None = None
        self._frames: dict[int, CameraFrame] = {}
        self._cameras: dict[int, NetworkCamera] = {}
        self._cameras_loaded = 0.0
        self._last_scene = 0.0
        self._last_image = 0.0
        self._tracks_shown: set[str] = set()
        self.steps = 0
        self.errors: list[float] = []
        self._detectors: dict[str, PersonDetector] = {}
        corners = np.array([p for room in scene.rooms for p in room.polygon], dtype=float)
        self._floor_lo, self._floor_hi = corners.min(axis=0), corners.max(axis=0)
        self._reset_state()

    # -- lifecycle ---------------------------------------------------------------------------

    def bootstrap(self) -> None:
        """Register the scene's space in the registry (first start) and map its cameras."""
        with self._factory() as session:
            self.space_id, self.camera_ids = bootstrap_space(session, self.scene)
        self._targets.space_id = self.space_id

    def _reset_state(self) -> None:
        robot = self.scene.robot
        self._rng = np.random.default_rng(self._seed)
        self._base = UnicycleBase.from_robot(robot, dt=_BASE_DT, rng=self._seed) if robot else None
        self._patrol = Patrol(robot.patrol, robot.limits) if robot and robot.patrol else None
        self.sim_time = 0.0
        self._tracker = FloorTracker(TrackerConfig(q=_TRACKER_Q))
        self.errors = []

    def _learn_background(self, camera: str) -> PersonDetector:
        # The empty home: no robot, the people far outside every camera's view.
        away = tuple((1e4, 1e4) for _ in self.scene.people)
        detector = PersonDetector()
        for i in range(3):
            frame = self._renderer.render(camera, WorldState(0.0, None, away), rng=i)
            detector.learn(frame.image)
        return detector

    def start(self) -> None:
        """Start the simulation thread."""
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name="twin", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the simulation thread (at the end of the current frame)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=30)
            self._thread = None

    @property
    def running(self) -> bool:
        """Whether the thread runs and is not paused."""
        return self._thread is not None and self._thread.is_alive() and not self._paused.is_set()

    def pause(self) -> None:
        """Hold the simulation clock until `resume`."""
        self._paused.set()

    def resume(self) -> None:
        """Continue after `pause`."""
        self._paused.clear()

    def reset(self) -> None:
        """Put the robot back at its start, the clock at 0 and forget the in-memory tracks."""
        with self._lock:
            self._reset_state()
            self._frames.clear()
        self._targets.clear_tracks(("robot", "person"))

    def set_rate(self, rate_hz: float) -> None:
        """Set the frame rate of the simulation (Hz)."""
        self.rate_hz = float(rate_hz)

    # -- reads -------------------------------------------------------------------------------

    def state(self) -> dict[str, Any]:
        """Return the twin's state: running, paused, sim time, robot pose, people, rate."""
        with self._lock:
            pose = self._base.state.pose if self._base is not None else None
            people = list(world_state(self.scene, self.sim_time).people)
            errors = np.array(self.errors[-200:])
            return {
                "enabled": True,
                "running": self.running,
                "paused": self._paused.is_set(),
                "scene": self.scene.name,
                "sim_time": self.sim_time,
                "steps": self.steps,
                "rate_hz": self.rate_hz,
                "robot": None if pose is None else {"x": pose.x, "y": pose.y, "theta": pose.yaw},
                "people": [{"x": x, "y": y} for x, y in people],
                "robot_error_rms_m": float(np.sqrt(np.mean(errors**2))) if errors.size else None,
                "cameras": self.camera_ids,
            }

    def frame(self, camera_id: int) -> CameraFrame | None:
        """Return the latest frame of camera `camera_id`, None when it has none."""
        with self._lock:
            return self._frames.get(camera_id)

    # -- the loop ----------------------------------------------------------------------------

    def _loop(self) -> None:
        # Built here, not at start-up: the cameras' static layers take seconds to render.
        for cam in self.scene.cameras:
            if self._stop.is_set():
                return
            self._detectors[cam.name] = self._learn_background(cam.name)
        next_time = time.monotonic()
        while not self._stop.is_set():
            period = 1.0 / max(self.rate_hz, 1e-3)
            if not self._paused.is_set():
                try:
                    self.step(period)
                except Exception:
                    log.exception("twin step failed")
            next_time = max(next_time + period, time.monotonic())
            self._stop.wait(max(0.0, next_time - time.monotonic()))

    def _network(self) -> dict[int, NetworkCamera]:
        # The registry's calibration may change (a run applied): reload it every second.
        now = time.monotonic()
        if now - self._cameras_loaded > 1.0:
            with self._factory() as session:
                self._cameras, _ = registry_cameras(session, list(self.camera_ids.values()))
            self._cameras_loaded = now
        return self._cameras

    def step(self, period: float) -> None:
        """Advance the simulation by `period` seconds and process one frame of every camera."""
        with self._lock:
            if self._base is not None:
                for _ in range(max(1, round(period / _BASE_DT))):
                    cmd = self._patrol.command(self._base.state.pose) if self._patrol else (0, 0)
                    self._base.step(*cmd)
                self.sim_time = self._base.state.time
            else:
                self.sim_time += period
            t = self.sim_time
            state = world_state(
                self.scene, t, self._base.state.pose if self._base is not None else None
            )
            network = self._network()
            frames: dict[int, CameraFrame] = {}
            marker_px: dict[int, tuple[np.ndarray, np.ndarray]] = {}
            people_px: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
            for spec in self.scene.cameras:
                camera_id = self.camera_ids.get(spec.name)
                if camera_id is None:
                    continue
                frame = self._renderer.render(spec.name, state, rng=self._rng)
                cf = CameraFrame(camera_id, spec.name, t, frame.image)
                marker = detect_marker(frame.image, self._marker_cfg) if self._marker_cfg else None
                if marker is not None:
                    marker_px[camera_id] = (marker.pixel, marker.cov)
                    cf.detections.append(
                        {"kind": "robot", "label": "robot", "pixel": marker.pixel.tolist()}
                    )
                detector = self._detectors.get(spec.name)
                persons = detector.detect(frame.image) if detector is not None else []
                for p in persons:
                    x, y, w, h = p.bbox
                    # The robot is foreground too: a blob around the marker is the robot.
                    if (
                        marker is not None
                        and x <= marker.pixel[0] <= x + w
                        and y <= marker.pixel[1] <= y + h
                    ):
                        continue
                    people_px.setdefault(camera_id, []).append((p.foot_pixel, p.cov))
                    cf.detections.append(
                        {
                            "kind": "person",
                            "label": "person",
                            "pixel": p.foot_pixel.tolist(),
                            "bbox": list(p.bbox),
                        }
                    )
                frames[camera_id] = cf
            self._frames = frames
            robot = self._locate_robot(state, network, marker_px)
            people = self._locate_people(network, people_px, robot)
            self._track(t, state, robot, people)
            self.steps += 1
        self._push_scene(state, frames)

    def _locate_robot(self, state, network, marker_px) -> tuple[np.ndarray, np.ndarray] | None:
        """Return the robot's centre on the floor and its covariance from the marker's
        detections, None when no calibrated camera saw it."""
        robot = self.scene.robot
        ids = [i for i in marker_px if i in network]
        if robot is None or robot.marker is None or not ids or state.robot is None:
            return None
        pixels = np.stack([marker_px[i][0] for i in ids])[:, None]
        cov = np.stack([marker_px[i][1] for i in ids])[:, None]
        est = locate_ml([network[i] for i in ids], pixels, robot.marker.height, pixel_cov=cov)
        if not est.valid[0]:
            return None
        # The marker sits at its offset in the robot frame; the target is the robot's centre.
        c, s = math.cos(state.robot.yaw), math.sin(state.robot.yaw)
        ox, oy = robot.marker.offset
        return est.xy[0] - np.array([c * ox - s * oy, s * ox + c * oy]), est.cov[0]

    def _locate_people(self, network, people_px, robot) -> list[tuple[np.ndarray, np.ndarray]]:
        """Return the people's floor positions and covariances: each detection located on its
        own (ML at Z = 0, one camera), grouped across cameras by distance, and each group fused
        by ML over its cameras."""
        singles: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = []
        for camera_id, dets in people_px.items():
            if camera_id not in network:
                continue
            px = np.stack([d[0] for d in dets])[None]
            cov = np.stack([d[1] for d in dets])[None]
            est = locate_ml([network[camera_id]], px, 0.0, pixel_cov=cov)
            for j, ok in enumerate(est.valid):
                if ok:
                    singles.append((camera_id, est.xy[j], dets[j][0], dets[j][1]))
        groups: list[list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]] = []
        for det in singles:
            for group in groups:
                if det[0] not in {g[0] for g in group} and (
                    np.linalg.norm(group[0][1] - det[1]) < _PERSON_GATE_M
                ):
                    group.append(det)
                    break
            else:
                groups.append([det])
        fused = []
        for group in groups:
            est = locate_ml(
                [network[g[0]] for g in group],
                np.stack([g[2] for g in group])[:, None],
                0.0,
                pixel_cov=np.stack([g[3] for g in group])[:, None],
            )
            # A camera that missed the marker sees the robot as foreground: not a person.
            near_robot = robot is not None and np.linalg.norm(est.xy[0] - robot[0]) < (
                _PERSON_GATE_M
            )
            if est.valid[0] and not near_robot and self._on_floor(est.xy[0]):
                fused.append((est.xy[0], est.cov[0]))
        return fused

    def _on_floor(self, xy: np.ndarray) -> bool:
        # A foreground blob whose foot point lands outside the home is not a person.
        return bool(np.all(xy >= self._floor_lo) and np.all(xy <= self._floor_hi))

    def _track(self, t, state, robot, people) -> None:
        """Update the tracker with this frame's floor positions (the robot's labelled) and
        publish every confirmed track updated now; the robot's error against the truth is kept
        for the state."""
        measurements = ([robot] if robot is not None else []) + people
        labels = (["robot"] if robot is not None else []) + [None] * len(people)
        xy = np.array([m[0] for m in measurements]).reshape(-1, 2)
        cov = np.array([m[1] for m in measurements]).reshape(-1, 2, 2)
        self._tracker.update(t, xy, cov, labels)
        for track in self._tracker.tracks(confirmed_only=True):
            if track.last_update != t:
                continue
            if track.label == "robot":
                label, kind = "robot", "robot"
                truth = np.array([state.robot.x, state.robot.y])
                self.errors.append(float(np.linalg.norm(track.xy - truth)))
            else:
                label, kind = f"person-{track.id}", "person"
            self._targets.update(label, kind, t, track.xy.tolist(), track.xy_cov.tolist())

    # -- the 3D scene ------------------------------------------------------------------------

    def _push_scene(self, state: WorldState, frames: dict[int, CameraFrame]) -> None:
        """Send the agents (true poses), the tracks (estimates) and the camera images to the
        3D scene, at most `_SCENE_HZ` times a second; the scene only records them and returns,
        its own thread draws."""
        scene = self._scene_sync.scene if self._scene_sync is not None else None
        if scene is None:
            return
        now = time.monotonic()
        if now - self._last_scene < 1.0 / _SCENE_HZ:
            return
        self._last_scene = now
        try:
            robot = self.scene.robot
            if state.robot is not None and robot is not None:
                scene.upsert_agent(
                    {
                        "id": "robot",
                        "kind": "robot",
                        "x": state.robot.x,
                        "y": state.robot.y,
                        "theta": state.robot.yaw,
                        "radius": robot.base_radius,
                        "height": robot.base_height,
                    }
                )
            for walker, (x, y) in zip(self.scene.people, state.people, strict=True):
                scene.upsert_agent(
                    {
                        "id": f"walker-{walker.name}",
                        "kind": "person",
                        "x": x,
                        "y": y,
                        "theta": 0.0,
                        "radius": walker.radius,
                        "height": walker.height,
                    }
                )
            _, items = self._targets.snapshot()
            live = {i["label"]: i for i in items if i["kind"] in ("robot", "person")}
            shown = set(live)
            for label, item in live.items():
                scene.set_track(label, self._targets.track(label)[-300:], item["cov"])
            for label in self._tracks_shown - shown:
                scene.set_track(label, [])  # a track that ended
            self._tracks_shown = shown
            if now - self._last_image >= 1.0 / _IMAGE_HZ:
                self._last_image = now
                for frame in frames.values():
                    scene.set_camera_image(frame.camera_id, frame.image)
        except Exception:
            log.exception("pushing the twin to the 3D scene failed")
