"""The spaces' trackers this process holds: their state, a space's tracker made on first use
(here, or in the trackers' process), a camera frame fed to it, and what it reports made into
live targets and told to the target listeners. Above it: server.services.tracking.sharing
(which process tracks each space) and server.services.tracking.service (ingest, the thread)."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from core.errors import IntspaceError
from core.localization import Occluders
from core.localization.tracking import (
    LIVE_STATES,
    FrameResult,
    TrackerConfig,
    TrackSnapshot,
    TrackState,
)
from server.db.models import Camera
from server.services.cameras import CameraNotPlaced, network_camera
from server.services.fanout import Fanout
from server.services.ownership import SpaceLocks
from server.services.targets import LiveTargets
from server.services.tracking.ingest import CameraFrame
from server.services.tracking.process import TrackerHost
from server.services.tracking.space import SpaceTracker

log = logging.getLogger("server.services.tracking")

# How often the tracker thread reloads the cameras' calibration (s).
_CAMERAS_RELOAD_S = 1.0


class SpaceTrackers:
    """The trackers of the spaces this process tracks (one per space) and what they hold in
    common; TrackingService is the whole service."""

    def __init__(
        self,
        factory: sessionmaker[Session],
        live: LiveTargets,
        config: TrackerConfig,
        latency: float,
        clock: Callable[[], float],
        shared: tuple[Fanout, SpaceLocks] | None,
        separate_process: bool,
    ) -> None:
        """Hold the options as TrackingService resolved them; `shared`: the link to the other
        processes and the spaces' locks, on a shared database."""
        self._factory = factory
        self.separate_process = separate_process
        self._host: TrackerHost | None = None
        self._host_lock = threading.Lock()
        self._live = live
        self.config = config
        self.latency = float(latency)
        self._clock = clock
        self._lock = threading.Lock()
        self._spaces: dict[int | None, SpaceTracker] = {}
        self._occluders: dict[int | None, Occluders] = {}
        self._wake = threading.Event()
        # Called on the tracker thread with (space id, confirmed or coasting snapshots a frame
        # updated, snapshots of the live targets that ended): the zones (server.services.
        # zones). They must not block.
        self.target_listeners: list[
            Callable[[int | None, tuple[TrackSnapshot, ...], tuple[TrackSnapshot, ...]], None]
        ] = []
        self._fanout: Fanout | None = None if shared is None else shared[0]
        self._locks: SpaceLocks | None = None if shared is None else shared[1]
        # (space, [[first id, last id] of stored detections, or {"c": camera, "t": time} of
        # an empty frame, ...]) that other processes took for a space tracked here.
        self._notified: list[tuple[int | None, list[Any]]] = []
        self._notified_lock = threading.Lock()
        # Held while spaces are taken over or given up; the spaces tried for at least once.
        self._ownership_lock = threading.RLock()
        self._tried: set[int | None] = set()
        # Set when notifications may have been missed (the listener reconnected).
        self._resync = threading.Event()

    def _space(self, space_id: int | None) -> SpaceTracker | None:
        """Return the tracker of a space (made on first use), None when another process
        runs it (shared database). Call with self._lock held."""
        space = self._spaces.get(space_id)
        if space is None and self._locks is None:
            space = self._new_space(space_id)
            self._spaces[space_id] = space
        return space

    def _new_space(self, space_id: int | None) -> SpaceTracker:
        with self._factory() as session:
            next_id = self._live.next_track_id(session, space_id)
        occluders = self._occluders.get(space_id)
        host = self._tracker_host() if self.separate_process else None
        return SpaceTracker(space_id, self.config, self.latency, next_id, occluders, host)

    def _tracker_host(self) -> TrackerHost:
        """Return the trackers' process, started on first use."""
        with self._host_lock:
            if self._host is None:
                self._host = TrackerHost()
            return self._host

    def released(self, space_id: int | None) -> float | None:
        """Return the capture time up to which the tracker of a space took its frames (a frame
        older than that is late), None when this process does not run it."""
        with self._lock:
            space = self._spaces.get(space_id)
            return None if space is None else space.buffer.released

    def owns(self, space_id: int | None) -> bool:
        """Whether this process runs the tracker of `space_id`."""
        with self._lock:
            return self._locks is None or space_id in self._spaces

    def set_floor_plan(self, space_id: int | None, occluders: Occluders) -> None:
        """Give the tracker of a space its walls and furniture (a camera hidden from a place
        is not expected to see a body there)."""
        with self._lock:
            self._occluders[space_id] = occluders
            space = self._spaces.get(space_id)
            if space is not None:
                space.tracker.occluders = occluders

    def floor_plan(self, space_id: int | None) -> Occluders | None:
        """Return a space's walls and furniture as given by `set_floor_plan`, None before."""
        with self._lock:
            return self._occluders.get(space_id)

    def _load_cameras(self, space: SpaceTracker) -> None:
        now = time.monotonic()
        if now - space.cameras_loaded < _CAMERAS_RELOAD_S:
            return
        space.cameras_loaded = now
        with self._factory() as session:
            rows = session.scalars(select(Camera).where(Camera.space_id == space.space_id)).all()
        with space.lock:
            for c in rows:
                try:
                    cam = network_camera(c)
                except CameraNotPlaced:
                    continue
                except IntspaceError as exc:
                    space.refused[c.id] = str(exc)
                    continue
                space.tracker.set_camera(c.id, cam)

    def _feed(self, space: SpaceTracker, f: CameraFrame) -> None:
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
                appearances=f.appearances,
            )
        except IntspaceError as exc:
            log.warning("camera %s frame at %.3f refused by the tracker: %s", f.camera_id, f.t, exc)
            return
        self._publish(space, result)

    def _publish(self, space: SpaceTracker, result: FrameResult) -> None:
        with self._live.batch():
            self._publish_frame(space, result)

    def _publish_frame(self, space: SpaceTracker, result: FrameResult) -> None:
        live = tuple(s for s in result.updated if s.state is not TrackState.TENTATIVE)
        for snap in live:
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
                state_cov=snap.cov.tolist(),
                hits=snap.hits,
            )
            space.states[snap.id] = snap.state
        if live:
            self._tell(space.space_id, live, ())
        self._publish_ended(space, result.ended)

    def _publish_ended(self, space: SpaceTracker, ended: tuple[TrackSnapshot, ...]) -> None:
        gone = []
        for snap in ended:
            if space.states.pop(snap.id, None) is not None:
                self._live.end(space.space_id, snap.id)
                gone.append(snap)
        if gone:
            self._tell(space.space_id, (), tuple(gone))

    def _tell(
        self,
        space_id: int | None,
        updated: tuple[TrackSnapshot, ...],
        ended: tuple[TrackSnapshot, ...],
    ) -> None:
        for listener in self.target_listeners:
            try:
                listener(space_id, updated, ended)
            except Exception:
                log.exception("a target listener failed")

    def _sync_states(self, space: SpaceTracker) -> None:
        for snap in space.tracker.tracks(states=LIVE_STATES):
            if snap.id in space.states and space.states[snap.id] is not snap.state:
                space.states[snap.id] = snap.state
                self._live.set_state(space.space_id, snap.id, str(snap.state))

    def tracks(self, space_id: int | None) -> tuple[TrackSnapshot, ...]:
        """Return the live tracks of a space (confirmed and coasting)."""
        with self._lock:
            space = self._spaces.get(space_id)
        if space is None:
            return ()
        with space.lock:
            return space.tracker.tracks(states=LIVE_STATES)
