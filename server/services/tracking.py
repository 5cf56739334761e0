"""The spaces' trackers: detections in, live targets out (spec 08's pipeline, service side).

`ingest` stores a batch of detections (the detections table, committed before it returns) and
queues them, one camera frame (camera, capture time) at a time, for the tracker of the
cameras' space. A background thread releases the queued frames in time order once they are
`latency` seconds old (so that cameras whose batches arrive out of step still reach the tracker
in order), feeds them to core.localization.tracking.Tracker, and hands its reports to the live
targets store. It also moves each tracker's clock on when no frame comes, so silent tracks
coast and end on time. The association and filtering are all in core; this module only moves
frames and results.

Times are Unix seconds on the service's clock.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from core.errors import IntspaceError
from core.localization import NetworkCamera, Occluders
from core.localization.tracking import (
    LIVE_STATES,
    FrameResult,
    ReorderBuffer,
    Tracker,
    TrackerConfig,
    TrackSnapshot,
    TrackState,
)
from server.db.models import Camera, Detection
from server.services.targets import LiveTargets

log = logging.getLogger(__name__)

# How often the tracker thread wakes (s), and how often it reloads the cameras' calibration.
_TICK_S = 0.02
_CAMERAS_RELOAD_S = 1.0


@dataclass(frozen=True)
class DetectionIn:
    """One detection to ingest: camera id, capture time (s), distorted pixel (2,), its 2x2
    covariance px^2, kind, height (m) of the measured point, label or None."""

    camera_id: int
    t: float
    pixel: tuple[float, float]
    cov: tuple[tuple[float, float], tuple[float, float]]
    kind: str
    height: float
    label: str | None = None


@dataclass(frozen=True)
class CameraFrame:
    """One camera frame's detections, ready for the tracker."""

    camera_id: int
    t: float
    pixels: np.ndarray
    cov: np.ndarray
    heights: np.ndarray
    kinds: list[str]
    labels: list[str | None]


@dataclass(frozen=True)
class IngestResult:
    """What `ingest` did: detections stored, camera frames queued, frames refused as late."""

    stored: int
    frames: int
    late: int


def camera_frames(detections: Sequence[DetectionIn]) -> list[CameraFrame]:
    """Return the detections split into camera frames (same camera and capture time), in time
    order."""
    by_frame: dict[tuple[int, float], list[DetectionIn]] = {}
    for d in detections:
        by_frame.setdefault((d.camera_id, d.t), []).append(d)
    frames = []
    for (camera_id, t), dets in sorted(by_frame.items(), key=lambda kv: (kv[0][1], kv[0][0])):
        frames.append(
            CameraFrame(
                camera_id=camera_id,
                t=t,
                pixels=np.array([d.pixel for d in dets], dtype=np.float64).reshape(-1, 2),
                cov=np.array([d.cov for d in dets], dtype=np.float64).reshape(-1, 2, 2),
                heights=np.array([d.height for d in dets], dtype=np.float64),
                kinds=[d.kind for d in dets],
                labels=[d.label for d in dets],
            )
        )
    return frames


class _SpaceTracker:
    """The tracker of one space, its reorder buffer and its cameras."""

    def __init__(
        self,
        space_id: int | None,
        config: TrackerConfig,
        latency: float,
        next_id: int,
        occluders: Occluders | None,
    ):
        self.space_id = space_id
        self.tracker = Tracker(config=config, next_id=next_id, occluders=occluders)
        self.buffer = ReorderBuffer(latency=latency)
        self.cameras_loaded = -float("inf")
        self.refused: dict[int, str] = {}
        self.states: dict[int, TrackState] = {}
        # Held while the tracker thread changes the tracker, so readers see a whole state.
        self.lock = threading.RLock()
        # Service time at which the space's world was held still (the twin paused), or None.
        self.held_since: float | None = None


class TrackingService:
    """One tracker per space, fed by `ingest`, run by one background thread."""

    def __init__(
        self,
        factory: sessionmaker[Session],
        live: LiveTargets,
        *,
        config: TrackerConfig | None = None,
        latency: float = 0.15,
        clock: Any = time.time,
    ) -> None:
        self._factory = factory
        self._live = live
        self.config = TrackerConfig() if config is None else config
        self.latency = float(latency)
        self._clock = clock
        self._lock = threading.Lock()
        self._spaces: dict[int | None, _SpaceTracker] = {}
        self._occluders: dict[int | None, Occluders] = {}
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.frames_processed = 0
        self.errors = 0

    # -- ingest ------------------------------------------------------------------------------

    def ingest(
        self, session: Session, detections: Sequence[DetectionIn], space_of: dict[int, int | None]
    ) -> IngestResult:
        """Store `detections` (committed when this returns) and queue them for the trackers
        of their cameras' spaces (`space_of`: camera id -> space id)."""
        if not detections:
            return IngestResult(0, 0, 0)
        session.execute(
            Detection.__table__.insert(),
            [
                {
                    "space_id": space_of.get(d.camera_id),
                    "camera_id": d.camera_id,
                    "t": d.t,
                    "u": d.pixel[0],
                    "v": d.pixel[1],
                    "cxx": d.cov[0][0],
                    "cxy": d.cov[0][1],
                    "cyy": d.cov[1][1],
                    "kind": d.kind,
                    "height": d.height,
                    "label": d.label,
                }
                for d in detections
            ],
        )
        session.commit()
        frames = camera_frames(detections)
        late = self.submit(frames, space_of)
        return IngestResult(len(detections), len(frames), late)

    def submit(self, frames: Sequence[CameraFrame], space_of: dict[int, int | None]) -> int:
        """Queue camera frames for their spaces' trackers; return how many came too late (older
        than what the tracker already processed)."""
        late = 0
        with self._lock:
            for f in frames:
                space = self._space(space_of.get(f.camera_id))
                if not space.buffer.push(f.t, f):
                    late += 1
        self._wake.set()
        return late

    def _space(self, space_id: int | None) -> _SpaceTracker:
        space = self._spaces.get(space_id)
        if space is None:
            with self._factory() as session:
                next_id = self._live.next_track_id(session, space_id)
            occluders = self._occluders.get(space_id)
            space = _SpaceTracker(space_id, self.config, self.latency, next_id, occluders)
            self._spaces[space_id] = space
        return space

    def set_floor_plan(self, space_id: int | None, occluders: Occluders) -> None:
        """Give the tracker of a space its walls and furniture (a camera hidden from a place
        is not expected to see a body there)."""
        with self._lock:
            self._occluders[space_id] = occluders
            space = self._spaces.get(space_id)
            if space is not None:
                space.tracker.occluders = occluders

    def hold(self, space_id: int | None) -> None:
        """Hold a space's tracks still: its world is paused (the twin), so no frame comes and
        its tracks must neither coast nor end until `release`."""
        with self._lock:
            space = self._space(space_id)
        with space.lock:
            if space.held_since is None:
                space.held_since = self._clock()

    def release(self, space_id: int | None) -> None:
        """Let a held space's tracks go on: their clock moves on by the time held."""
        with self._lock:
            space = self._space(space_id)
        with space.lock:
            if space.held_since is not None:
                space.tracker.shift(max(0.0, self._clock() - space.held_since))
                space.held_since = None

    def reset(self, space_id: int | None) -> None:
        """Forget the tracks of a space (its targets end) and start its tracker afresh."""
        with self._lock:
            old = self._spaces.pop(space_id, None)
            if old is not None:
                for snap in old.tracker.tracks(states=LIVE_STATES):
                    self._live.end(space_id, snap.id)
            self._space(space_id)

    # -- the thread --------------------------------------------------------------------------

    def start(self) -> None:
        """Start the tracker thread."""
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name="tracker", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the tracker thread."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
            self._thread = None

    def _loop(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(_TICK_S)
            self._wake.clear()
            try:
                self.process(self._clock())
            except Exception:
                self.errors += 1
                log.exception("tracking failed")

    def process(self, now: float) -> int:
        """Feed every frame older than now - latency to its tracker and move the trackers'
        clocks to now - latency; return the frames processed."""
        with self._lock:
            spaces = list(self._spaces.values())
            ready = [(space, space.buffer.pop_ready(now)) for space in spaces]
        done = 0
        for space, frames in ready:
            self._load_cameras(space)
            with space.lock:
                for _, frame in frames:
                    assert isinstance(frame, CameraFrame)
                    self._feed(space, frame)
                    done += 1
                horizon = now - self.latency
                t = space.tracker.time
                moving = space.held_since is None
                if moving and t is not None and horizon > t and len(space.tracker):
                    ended = space.tracker.advance(horizon)
                    self._publish_ended(space, ended)
                self._sync_states(space)
        self.frames_processed += done
        return done

    def _load_cameras(self, space: _SpaceTracker) -> None:
        now = time.monotonic()
        if now - space.cameras_loaded < _CAMERAS_RELOAD_S:
            return
        space.cameras_loaded = now
        with self._factory() as session:
            rows = session.scalars(select(Camera).where(Camera.space_id == space.space_id)).all()
        with space.lock:
            for c in rows:
                if c.K is None or c.T_world_camera is None:
                    continue
                try:
                    cam = NetworkCamera.from_pose(
                        c.K, c.dist, c.T_world_camera, (c.width, c.height), c.name
                    )
                except IntspaceError as exc:
                    space.refused[c.id] = str(exc)
                    continue
                space.tracker.set_camera(c.id, cam)

    def _feed(self, space: _SpaceTracker, f: CameraFrame) -> None:
        if f.camera_id not in space.tracker.cameras:
            space.cameras_loaded = -float("inf")
            self._load_cameras(space)
            if f.camera_id not in space.tracker.cameras:
                return  # not calibrated (the API refuses such cameras; the twin may race)
        t = space.tracker.time
        if t is not None and f.t < t:
            space.buffer.late += 1  # released with the window, but behind the tracker's clock
            return
        try:
            result = space.tracker.update(
                f.camera_id,
                f.t,
                f.pixels,
                f.cov,
                heights=f.heights,
                kinds=f.kinds,
                labels=f.labels,
            )
        except IntspaceError as exc:
            log.warning("camera %s frame at %.3f refused by the tracker: %s", f.camera_id, f.t, exc)
            return
        self._publish(space, result)

    def _publish(self, space: _SpaceTracker, result: FrameResult) -> None:
        for snap in result.updated:
            if snap.state is TrackState.TENTATIVE:
                continue
            self._live.update(
                space.space_id,
                snap.id,
                label=snap.label,
                kind=snap.kind,
                state=str(snap.state),
                first_seen=snap.first_seen,
                t=snap.t,
                xy=[float(snap.x[0]), float(snap.x[1])],
                cov=snap.xy_cov.tolist(),
                velocity=[float(snap.x[2]), float(snap.x[3])],
            )
            space.states[snap.id] = snap.state
        self._publish_ended(space, result.ended)

    def _publish_ended(self, space: _SpaceTracker, ended: tuple[TrackSnapshot, ...]) -> None:
        for snap in ended:
            if space.states.pop(snap.id, None) is not None:
                self._live.end(space.space_id, snap.id)

    def _sync_states(self, space: _SpaceTracker) -> None:
        for snap in space.tracker.tracks(states=LIVE_STATES):
            if snap.id in space.states and space.states[snap.id] is not snap.state:
                space.states[snap.id] = snap.state
                self._live.set_state(space.space_id, snap.id, str(snap.state))

    # -- reads -------------------------------------------------------------------------------

    def tracks(self, space_id: int | None) -> tuple[TrackSnapshot, ...]:
        """Return the live tracks of a space (confirmed and coasting)."""
        with self._lock:
            space = self._spaces.get(space_id)
        if space is None:
            return ()
        with space.lock:
            return space.tracker.tracks(states=LIVE_STATES)
