"""The running digital twin: the default home simulated in a background thread.

The robot patrols and the scene's people walk; at `rate_hz` every ceiling camera's frame is
rendered and its robot marker and people detected (core.localization.detections.detect_frame,
what a camera node calls too). The detections, unlabelled and stamped with the frame's capture
time on the service's clock (the twin's clock mapped to Unix seconds), go to the same ingest as
POST /observations (server.services.tracking): stored, then tracked by the space's one tracker.
The latest frame of each camera and its detections are kept for the API; the live 3D scene gets
the agents, tracks and images at a throttled rate. Each loop reports its cameras' health to the
service's camera health book, as a camera node's heartbeat does for its cameras (frame rate,
frames skipped, the newest frame's time): a paused twin's cameras are stalled, a dead loop's
offline.

The twin's scene is also the calibration object of the "network" calibration runs. Its home's
space in the registry is set up by server.services.twin_home.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from sqlalchemy.orm import Session, sessionmaker

from core.localization import NetworkCamera
from core.localization.detect import MarkerDetectorConfig, PersonDetector
from core.localization.detections import detect_frame
from core.sim import Scene, UnicycleBase, WorldState, world_state
from core.sim.motion import Patrol
from core.sim.occluders import scene_occluders
from core.sim.render import renderer_for
from server.schemas.registry import CameraHeartbeat
from server.schemas.twin import TwinState
from server.services._loop_thread import LoopThread
from server.services.cameras import registry_cameras
from server.services.tracking import DetectionIn
from server.services.twin_home import bootstrap_space, register_devices

if TYPE_CHECKING:
    from server.services.camera_health import CameraHealthBook
    from server.services.scene_sync import SceneSync
    from server.services.targets import LiveTargets
    from server.services.tracking import TrackingService

log = logging.getLogger(__name__)

# Physics step of the robot base (s); the twin steps it as often as a frame period needs.
_BASE_DT = 0.05
# Pushes to the 3D scene (agents, tracks) and camera images, at most this often (Hz).
_SCENE_HZ = 5.0
# How many of the robot track's errors against the truth the state keeps.
_ERRORS_KEPT = 2000
# The most a late step advances the simulation (seconds): the whole frame periods since the
# previous step, up to this (a stalled machine), so the world never jumps further at once.
MAX_CATCH_UP_S = 1.0
_IMAGE_HZ = 1.0
# The frame rate reported as the cameras' health is measured over this many recent frames.
_FPS_FRAMES = 10


@dataclass
class TwinFrame:
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
        tracking: TrackingService | None,
        scene_sync: SceneSync | None = None,
        *,
        rate_hz: float = 5.0,
        seed: int = 0,
        clock: Any = time.time,
        detect: bool = True,
        health: CameraHealthBook | None = None,
    ) -> None:
        self.scene = scene
        # False: the twin only renders; camera nodes read its streams and post the detections.
        self.detect = detect
        self.space_id: int | None = None
        self.camera_ids: dict[str, int] = {}
        self._factory = factory
        self._targets = targets
        self._tracking = tracking
        self._clock = clock
        # Unix time of the twin's clock zero: a frame at sim time s was captured at epoch + s.
        self._epoch = clock()
        self._scene_sync = scene_sync
        # Where the cameras' health goes. Without detection the camera nodes reading the twin's
        # streams report it, as they do for any camera, so the twin does not speak for them.
        self._health = health if detect else None
        # Capture times of the latest instants (their frame rate) and the frame periods skipped
        # since the start because steps came late (the cameras' dropped frames).
        self._frame_times: deque[float] = deque(maxlen=_FPS_FRAMES + 1)
        self._last_frame_t: float | None = None  # kept across a pause or a reset
        self.dropped = 0
        self._seed = seed
        self.rate_hz = float(rate_hz)
        self._renderer = renderer_for(scene)
        self._marker_cfg = (
            MarkerDetectorConfig(colour=scene.robot.marker.colour, radius=scene.robot.marker.radius)
            if scene.robot is not None and scene.robot.marker is not None
            else None
        )
        self._mast_cfg = (
            MarkerDetectorConfig(colour=scene.robot.mast_marker.colour)
            if scene.robot is not None and scene.robot.mast_marker is not None
            else None
        )
        self._lock = threading.Lock()
        # Set to cut the loop's wait short (a new rate, a stop): a slow rate must not hold it.
        self._wake = threading.Event()
        self._last_step = time.monotonic()
        self._paused = threading.Event()
        self._runner = LoopThread(self._loop, "twin", join_timeout=30, wake=self._wake)
        self._frames: dict[int, TwinFrame] = {}
        self._cameras: dict[int, NetworkCamera] = {}
        self._cameras_loaded = -float("inf")
        self._last_scene = 0.0
        self._last_image = 0.0
        self._tracks_shown: set[str] = set()
        self._in_scene = False
        self.steps = 0
        self.errors: deque[float] = deque(maxlen=_ERRORS_KEPT)
        self._detectors: dict[str, PersonDetector] = {}
        self._reset_state()

    # -- lifecycle ---------------------------------------------------------------------------

    def bootstrap(self) -> None:
        """Register the scene's space in the registry (first start) and map its cameras."""
        with self._factory() as session:
            self.space_id, self.camera_ids = bootstrap_space(session, self.scene)
            register_devices(session, self.space_id, self.scene)
        if self._tracking is not None:
            # The floor plan is what an installer knows of the home (not the twin's truth).
            self._tracking.set_floor_plan(self.space_id, scene_occluders(self.scene))

    def _reset_state(self) -> None:
        robot = self.scene.robot
        self._rng = np.random.default_rng(self._seed)
        self._base = UnicycleBase.from_robot(robot, dt=_BASE_DT, rng=self._seed) if robot else None
        self._patrol = Patrol(robot.patrol, robot.limits) if robot and robot.patrol else None
        self.sim_time = 0.0
        self._pose = self._base.state.pose if self._base is not None else None
        self._epoch = self._clock()
        self._frame_times.clear()
        self.errors = deque(maxlen=_ERRORS_KEPT)
        # (capture time, sim time, robot x, robot y) of recent frames, for scoring only.
        self._truth: deque[tuple[float, float, float, float]] = deque(maxlen=_ERRORS_KEPT)
        self._scored_until = -float("inf")

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
        self._runner.start()

    def stop(self) -> None:
        """Stop the simulation thread (at the end of the current frame)."""
        self._runner.stop()

    @property
    def running(self) -> bool:
        """Whether the thread runs and is not paused."""
        return self._runner.alive and not self._paused.is_set()

    @property
    def stuck(self) -> bool:
        """Whether the twin should run but has not finished a frame for 10 s or 5 periods."""
        if self._paused.is_set() or not self._runner.started:
            return False
        late = max(10.0, 5.0 / max(self.rate_hz, 1e-3))
        return not self._runner.alive or time.monotonic() - self._last_step > late

    def pause(self) -> None:
        """Hold the simulation clock (and the space's tracks) until `resume`."""
        self._paused.set()
        if self._tracking is not None:
            self._tracking.hold(self.space_id)

    def resume(self) -> None:
        """Continue after `pause`; the twin's clock goes on from the service's clock now."""
        with self._lock:
            self._epoch = self._clock() - self.sim_time
            self._frame_times.clear()  # the pause is not a slow frame rate
        if self._tracking is not None:
            self._tracking.release(self.space_id)
        self._paused.clear()

    def reset(self) -> None:
        """Put the robot back at its start, the clock at 0 and forget the in-memory tracks."""
        with self._lock:
            self._reset_state()
            self._frames.clear()
        if self._tracking is not None:
            self._tracking.reset(self.space_id)

    def set_rate(self, rate_hz: float) -> None:
        """Set the frame rate of the simulation (Hz); it takes effect at once."""
        self.rate_hz = float(rate_hz)
        self._wake.set()

    # -- reads -------------------------------------------------------------------------------

    def state(self) -> TwinState:
        """Return the twin's state: running, paused, sim time, robot pose, people, rate."""
        with self._lock:
            pose = self._pose  # the published instant's, read with its sim_time
            people = list(world_state(self.scene, self.sim_time).people)
            errors = np.array(list(self.errors)[-200:])
            return TwinState(
                enabled=True,
                running=self.running,
                paused=self._paused.is_set(),
                scene=self.scene.name,
                space_id=self.space_id,
                sim_time=self.sim_time,
                steps=self.steps,
                rate_hz=self.rate_hz,
                stuck=self.stuck,
                last_step_age_s=time.monotonic() - self._last_step,
                robot=None if pose is None else {"x": pose.x, "y": pose.y, "theta": pose.yaw},
                people=[{"x": x, "y": y} for x, y in people],
                robot_error_rms_m=float(np.sqrt(np.mean(errors**2))) if errors.size else None,
                cameras=self.camera_ids,
            )

    def frame(self, camera_id: int) -> TwinFrame | None:
        """Return the latest frame of camera `camera_id`, None when it has none."""
        with self._lock:
            return self._frames.get(camera_id)

    # -- the loop ----------------------------------------------------------------------------

    def _loop(self) -> None:
        # Built here, not at start-up: the cameras' static layers take seconds to render.
        for cam in self.scene.cameras:
            if self._runner.stopping:
                return
            self._detectors[cam.name] = self._learn_background(cam.name)
        next_time = time.monotonic()
        last: float | None = None
        owed = 0.0  # real time not yet simulated (s)
        while not self._runner.stopping:
            period = 1.0 / max(self.rate_hz, 1e-3)
            if not self._paused.is_set():
                # The home keeps the service's time, as real cameras do: when steps come late
                # (a loaded machine) each advances the world by the whole periods that have
                # passed, so the frames' stamps and the motion they show agree, and there are
                # fewer frames. Advancing by one period regardless slowed the world while the
                # stamps kept real time: a walker seemed to stop and jump, and the tracker
                # could lose it. Whole periods keep the instants on one grid, whatever the
                # load (two services on one home simulate the same instants).
                now = time.monotonic()
                if last is not None:
                    owed = min(owed + now - last, MAX_CATCH_UP_S)
                last = now
                most = max(1, int(MAX_CATCH_UP_S / period + 1e-9))
                periods = max(1, min(round(owed / period), most))
                owed -= periods * period
                self.dropped += periods - 1
                try:
                    self.step(periods * period)
                except Exception:
                    log.exception("twin step failed")
            else:
                last, owed = None, 0.0
            self._last_step = time.monotonic()
            self._report_health()
            next_time = max(next_time + period, time.monotonic())
            if self._wake.wait(max(0.0, next_time - time.monotonic())):
                self._wake.clear()
                next_time = time.monotonic()

    def _report_health(self) -> None:
        """Report every camera's health to the service's book, as a camera node's heartbeat
        does: the frame rate of the latest instants (the set rate before two exist), the frame
        periods skipped, the newest frame's capture time; the twin keeps the service's clock
        (offset 0) and its cameras never stall or reconnect as streams do."""
        if self._health is None:
            return
        with self._lock:
            times = list(self._frame_times)
            last = self._last_frame_t
        if len(times) >= 2 and times[-1] > times[0]:
            fps = (len(times) - 1) / (times[-1] - times[0])
        else:
            fps = self.rate_hz if last is not None else 0.0
        beat = CameraHeartbeat(
            fps=min(fps, 10_000.0),
            dropped=self.dropped,
            clock_offset_s=0.0,
            last_frame_t=last,
        )
        for camera_id in self.camera_ids.values():
            self._health.beat(camera_id, beat)

    def _network(self) -> dict[int, NetworkCamera]:
        # The registry's calibration, as a camera node reads it: the detector locates a person
        # at the body's axis with it. A calibration run may change it: reload every second.
        now = time.monotonic()
        if now - self._cameras_loaded > 1.0:
            with self._factory() as session:
                self._cameras, _ = registry_cameras(session, list(self.camera_ids.values()))
            self._cameras_loaded = now
        return self._cameras

    def step(self, period: float) -> None:
        """Advance the simulation by `period` seconds and process one frame of every camera:
        render, detect, and hand the detections to the space's tracker."""
        with self._lock:
            if self._base is not None:
                for _ in range(max(1, round(period / _BASE_DT))):
                    cmd = self._patrol.command(self._base.state.pose) if self._patrol else (0, 0)
                    self._base.step(*cmd)
                t = self._base.state.time
            else:
                t = self.sim_time + period
            state = world_state(
                self.scene, t, self._base.state.pose if self._base is not None else None
            )
            rng, base = self._rng, self._base
        # Every camera's frame of the instant is rendered first, outside the lock; then the
        # instant is published (GET /twin, the streams) and its frames stamped at once, as a
        # synchronised camera network delivers its frames: the twin's clock maps to the
        # service's so that instant t happens when its frames exist. Rendering them is the
        # cost of simulating a home, not a delay of its cameras. Each instant is stamped when it
        # is published, so the stamps keep their order.
        rendered = [
            (spec.name, camera_id, self._renderer.render(spec.name, state, rng=rng).image)
            for spec in self.scene.cameras
            if (camera_id := self.camera_ids.get(spec.name)) is not None
        ]
        with self._lock:
            if self._paused.is_set() or self._base is not base or self.sim_time > t:
                return  # paused or reset while rendering: the instant never happened
            self.sim_time = t
            self._pose = state.robot
            self._epoch = self._clock() - t
            stamp = self._epoch + t
            frames = {cid: TwinFrame(cid, name, stamp, image) for name, cid, image in rendered}
            self._frames.update(frames)
            self._frame_times.append(stamp)
            self._last_frame_t = stamp
        robot = self.scene.robot
        marker_height = robot.marker.height if robot is not None and robot.marker else 0.0
        network = self._network()
        detections: list[DetectionIn] = []
        empty: list[tuple[int, float]] = []
        for shown in list(frames.values()):
            camera_id = shown.camera_id
            # Published again with its detections once they are known.
            cf = TwinFrame(camera_id, shown.name, stamp, shown.image)
            found = (
                detect_frame(
                    cf.image,
                    marker=self._marker_cfg,
                    marker_height=marker_height,
                    people=self._detectors.get(cf.name),
                    camera=network.get(camera_id),
                    mast=self._mast_cfg,
                )
                if self.detect
                else []
            )
            for d in found:
                cf.detections.append(d.to_dict())
                # The marker's colour is this robot's own: its detection names the robot.
                label = robot.name if d.kind == "robot" and robot is not None else None
                detections.append(
                    DetectionIn(
                        camera_id=camera_id,
                        t=stamp,
                        pixel=(float(d.pixel[0]), float(d.pixel[1])),
                        cov=(
                            (float(d.cov[0, 0]), float(d.cov[0, 1])),
                            (float(d.cov[1, 0]), float(d.cov[1, 1])),
                        ),
                        kind=d.kind,
                        height=d.height,
                        label=label,
                    )
                )
            if not found:
                # A frame in which nothing was found still tells the tracker that this camera
                # looked at that time: its reorder window need not wait for it.
                empty.append((camera_id, stamp))
            frames[camera_id] = cf
            with self._lock:
                self._frames[camera_id] = cf
        if self._tracking is not None and self.detect:
            # The instant's frames in one transaction: the tracker takes them together anyway,
            # once the last camera's has come.
            with self._factory() as session:
                space_of: dict[int, int | None] = dict.fromkeys(frames, self.space_id)
                self._tracking.ingest(session, detections, space_of, empty=empty)
        with self._lock:
            self.steps += 1
        self._score_robot(state)
        self._push_scene(state, frames)

    def _score_robot(self, state: WorldState) -> None:
        """Keep the error of the live robot track against the twin's robot at the track's own
        time (the truth is used for scoring only, never by the pipeline)."""
        if state.robot is None:
            return
        with self._lock:
            self._truth.append(
                (self._epoch + self.sim_time, self.sim_time, state.robot.x, state.robot.y)
            )
        robot = self.scene.robot
        # The robot's target at its latest update, scored once per update; its time and
        # position are read together, since the tracker updates them meanwhile.
        latest = self._targets.latest(robot.name) if robot is not None else None
        if latest is None:
            return
        phase, t, xy = latest
        if phase != "confirmed" or t <= self._scored_until:
            return
        truth = self.truth_at(np.array([t]))
        # An update the truth's history does not reach yet is scored at the next step.
        if truth is not None and np.all(np.isfinite(truth)):
            self._scored_until = t
            self.errors.append(float(np.linalg.norm(np.asarray(xy) - truth[0])))

    def sim_time_at(self, stamps: np.ndarray) -> np.ndarray:
        """Return the twin's simulated times (N,) of capture times `stamps` (N,) Unix seconds
        (NaN outside the recent history)."""
        with self._lock:
            hist = np.array(self._truth, dtype=np.float64).reshape(-1, 4)
        if hist.shape[0] < 2:
            return np.full(np.shape(stamps), np.nan)
        return np.interp(stamps, hist[:, 0], hist[:, 1], left=np.nan, right=np.nan)

    def truth_at(self, stamps: np.ndarray) -> np.ndarray | None:
        """Return the robot's true floor position (N, 2) at capture times `stamps` (N,),
        linearly between frames (NaN outside the recent history); None without a robot."""
        with self._lock:
            hist = np.array(self._truth, dtype=np.float64).reshape(-1, 4)
        if hist.shape[0] < 2:
            return None
        x = np.interp(stamps, hist[:, 0], hist[:, 2], left=np.nan, right=np.nan)
        y = np.interp(stamps, hist[:, 0], hist[:, 3], left=np.nan, right=np.nan)
        return np.column_stack([x, y])

    # -- the 3D scene ------------------------------------------------------------------------

    def _push_scene(self, state: WorldState, frames: dict[int, TwinFrame]) -> None:
        """Send the agents (true poses), the tracks (estimates) and the camera images to the
        3D scene, at most `_SCENE_HZ` times a second; the scene only records them and returns,
        its own thread draws."""
        sync = self._scene_sync
        scene = sync.scene if sync is not None else None
        if sync is None or scene is None:
            return
        now = time.monotonic()
        if now - self._last_scene < 1.0 / _SCENE_HZ:
            return
        self._last_scene = now
        try:
            if not sync.shows(self.space_id):
                self._leave_scene(scene)
                return
            self._in_scene = True
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
            live = {
                i["label"]: i
                for i in items
                if i["kind"] in ("robot", "person") and i["space_id"] == self.space_id
            }
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

    def _leave_scene(self, scene: Any) -> None:
        """Take the twin's bodies and tracks out of the 3D scene while it shows another space
        (once: nothing is sent while it stays away)."""
        if not self._in_scene:
            return
        self._in_scene = False
        if self.scene.robot is not None:
            scene.remove_agent("robot")
        for walker in self.scene.people:
            scene.remove_agent(f"walker-{walker.name}")
        for label in self._tracks_shown:
            scene.set_track(label, [])
        self._tracks_shown = set()
