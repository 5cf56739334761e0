"""The tracking service: `ingest` stores detections and queues them for their space's tracker;
a background thread releases the queued frames in time order once they are `latency` seconds
old (or sooner once every camera heard from has delivered frames as recent), feeds them to the
trackers, moves the trackers' clocks on when no frame comes (so silent tracks coast and end on
time), and on a shared database polls ownership and passes on the target changes. A space's
tracks may be held still (the twin paused), let go, or reset, here or in the process that
tracks it."""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from typing import Any, cast

from sqlalchemy import Table, insert
from sqlalchemy.orm import Session, sessionmaker

from core.localization.tracking import LIVE_STATES, TrackerConfig
from server.db.models import Detection
from server.services._loop_thread import LoopThread
from server.services.fanout import Fanout
from server.services.ownership import SpaceLocks
from server.services.targets import LiveTargets
from server.services.tracking.ingest import (
    CameraFrame,
    DetectionIn,
    FrameDelays,
    IngestResult,
    camera_frames,
    empty_frame,
)
from server.services.tracking.process import TrackerProcessError
from server.services.tracking.sharing import OWNERSHIP_POLL_S, SharedTrackers
from server.services.tracking.space import SpaceTracker
from server.services.tracking.wire import CONTROL_CHANNEL, DETECTIONS_CHANNEL, TARGETS_CHANNEL

log = logging.getLogger("server.services.tracking")

# How often the tracker thread wakes (s).
_TICK_S = 0.02


class TrackingService(SharedTrackers):
    """One tracker per space, fed by `ingest`, run by one background thread. With
    `shared_database_url` (PostgreSQL), the processes sharing that database share the spaces'
    trackers (server.services.tracking.sharing). With `separate_process` (by default: on a
    shared database) the core trackers run in a child process (`TrackerHost`), started with
    the first space."""

    def __init__(
        self,
        factory: sessionmaker[Session],
        live: LiveTargets,
        *,
        config: TrackerConfig | None = None,
        latency: float = 1.0,
        clock: Any = time.time,
        shared_database_url: str | None = None,
        separate_process: bool | None = None,
    ) -> None:
        if separate_process is None:
            separate_process = shared_database_url is not None
        shared = None
        if shared_database_url is not None:
            shared = (Fanout(shared_database_url), SpaceLocks(shared_database_url))
        config = TrackerConfig() if config is None else config
        super().__init__(factory, live, config, latency, clock, shared, bool(separate_process))
        self._runner = LoopThread(self._loop, "tracker", join_timeout=10, wake=self._wake)
        self.frames_processed = 0
        self.errors = 0
        self.delays = FrameDelays()
        if self._fanout is not None:
            self._fanout.subscribe(TARGETS_CHANNEL, self._on_targets)
            self._fanout.subscribe(DETECTIONS_CHANNEL, self._on_detections)
            self._fanout.subscribe(CONTROL_CHANNEL, self._on_control)
            self._fanout.on_reconnect(self._resync.set)

    # -- ingest ------------------------------------------------------------------------------

    def ingest(
        self,
        session: Session,
        detections: Sequence[DetectionIn],
        space_of: dict[int, int | None],
        *,
        empty: Sequence[tuple[int, float]] = (),
    ) -> IngestResult:
        """Store `detections` (committed when this returns) and queue them for the trackers
        of their cameras' spaces (`space_of`: camera id -> space id), with the camera frames
        `empty` ((camera id, capture time) pairs) in which nothing was detected: those are not
        stored, they only tell the trackers that the cameras looked at those times."""
        blank = [empty_frame(int(c), float(t)) for c, t in empty]
        if not detections:
            return IngestResult(0, len(blank), self.submit(blank, space_of) if blank else 0)
        rows = [
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
                "box": None if d.box is None else list(d.box),
                "score": d.score,
                "cut": None if d.cut is None else list(d.cut),
                "appearance": None if d.appearance is None else list(d.appearance),
            }
            for d in detections
        ]
        ids: list[int] | None = None
        if self._locks is not None:
            # The rows' ids tell the space's tracker, maybe in another process, what to read.
            stmt = insert(Detection).returning(Detection.id, sort_by_parameter_order=True)
            ids = list(session.scalars(stmt, rows))
        else:
            session.execute(cast(Table, Detection.__table__).insert(), rows)
        session.commit()
        stored = len(detections)
        if not all(d.tracked for d in detections):
            # Stored, but no floor position: not for the tracker.
            keep = [k for k, d in enumerate(detections) if d.tracked]
            detections = [detections[k] for k in keep]
            ids = None if ids is None else [ids[k] for k in keep]
        frames = camera_frames(detections, ids)
        if blank:
            frames = sorted(frames + blank, key=lambda f: (f.t, f.camera_id))
        late = self.submit(frames, space_of) if frames else 0
        return IngestResult(stored, len(frames), late)

    def hold(self, space_id: int | None) -> None:
        """Hold a space's tracks still: its world is paused (the twin), so no frame comes and
        its tracks must neither coast nor end until `release`."""
        space = self._here_or_forward(space_id, "hold")
        if space is None:
            return
        with space.lock:
            if space.held_since is None:
                space.held_since = self._clock()

    def release(self, space_id: int | None) -> None:
        """Let a held space's tracks go on: their clock moves on by the time held."""
        space = self._here_or_forward(space_id, "release")
        if space is None:
            return
        with space.lock:
            if space.held_since is not None:
                space.tracker.shift(max(0.0, self._clock() - space.held_since))
                space.held_since = None

    def _here_or_forward(self, space_id: int | None, op: str) -> SpaceTracker | None:
        """Return the tracker of a space tracked here (made on first use); else ask the process
        that tracks it to do `op`, and return None."""
        with self._lock:
            space = self._space(space_id)
        if space is None:
            self._forward(space_id, op)
        return space

    def reset(self, space_id: int | None) -> None:
        """Forget the tracks of a space (its targets end) and start its tracker afresh."""
        with self._lock:
            elsewhere = self._locks is not None and space_id not in self._spaces
            if not elsewhere:
                old = self._spaces.pop(space_id, None)
                if old is not None:
                    gone = old.tracker.tracks(states=LIVE_STATES)
                    for snap in gone:
                        self._live.end(space_id, snap.id)
                    old.close()
                    if gone:
                        self._tell(space_id, (), gone)
                self._spaces[space_id] = self._new_space(space_id)
        if elsewhere:
            self._forward(space_id, "reset")

    def _forward(self, space_id: int | None, op: str) -> None:
        """Ask the process that runs a space's tracker to hold, release or reset it."""
        if self._fanout is not None:
            self._fanout.publish(CONTROL_CHANNEL, {"space": space_id}, [op])

    def _on_control(self, message: dict[str, Any]) -> None:
        """Hold, release or reset a space tracked here, as another process asked (its twin
        paused, resumed or was reset); listener thread."""
        space_id = message.get("space")
        with self._lock:
            if space_id not in self._spaces:
                return
        for op in message.get("items", ()):
            if op == "hold":
                self.hold(space_id)
            elif op == "release":
                self.release(space_id)
            elif op == "reset":
                self.reset(space_id)

    # -- the thread --------------------------------------------------------------------------

    def start(self) -> None:
        """Start the tracker thread (and, on a shared database, listening to the others)."""
        if self._fanout is not None:
            self._live.publishing = True
            self._fanout.start()
        self._runner.start()

    def stop(self) -> None:
        """Stop the tracker thread; on a shared database give the spaces up to the others."""
        if self._runner.stop():
            if len(self.delays):
                log.info("tracker: %s", self.delays.describe())
        if self._locks is not None:
            self._publish_changes()
            self._locks.close()
        if self._fanout is not None:
            self._fanout.stop()
        with self._host_lock:
            host, self._host = self._host, None
        if host is not None:
            host.close()

    def _loop(self) -> None:
        last_poll = -float("inf")
        if self.separate_process:
            # Started here rather than with the first space: the first frames do not wait
            # for it (the first host of a process starts the fork server, a second or two).
            try:
                self._tracker_host()
            except Exception:
                log.exception("the trackers' process did not start; trying with the first space")
        while not self._runner.stopping:
            self._wake.wait(_TICK_S)
            self._wake.clear()
            try:
                if self._locks is not None:
                    beat = time.monotonic() - last_poll >= OWNERSHIP_POLL_S
                    if beat:
                        last_poll = time.monotonic()
                        self._poll_ownership()
                    self._read_notified()
                    if self._resync.is_set():
                        self._resync.clear()
                        self._catch_up()
                self.process(self._clock())
                if self._fanout is not None:
                    self._publish_changes()
                    if beat:
                        self._publish_live()
            except TrackerProcessError:
                self.errors += 1
                try:
                    self._recover()
                except Exception:
                    log.exception("restarting the trackers' process failed; trying again")
            except Exception:
                self.errors += 1
                log.exception("tracking failed")

    def process(self, now: float) -> int:
        """Feed every frame the reorder buffers release (older than now - latency, or than
        the cameras' watermark) to its tracker and move the trackers' clocks to the released
        time; return the frames processed."""
        with self._lock:
            spaces = list(self._spaces.values())
            # A tracker that never had a frame does not close its window: its first frame is
            # taken however late it comes, as when the tracker is made for that frame.
            ready = [
                (space, space.buffer.pop_ready(now))
                for space in spaces
                if len(space.buffer) or space.tracker.time is not None
            ]
        released = self._clock()
        done = 0
        for space, frames in ready:
            self._load_cameras(space)
            with space.lock:
                for _, item in frames:
                    frame, arrived = cast(tuple[CameraFrame, float], item)
                    self._feed(space, frame)
                    self.delays.frame(frame.t, arrived, released, self._clock())
                    done += 1
                horizon = space.buffer.released
                t = space.tracker.time
                moving = space.held_since is None
                if moving and t is not None and horizon > t and len(space.tracker):
                    ended = space.tracker.advance(horizon)
                    self._publish_ended(space, ended)
                self._sync_states(space)
        self.frames_processed += done
        return done
