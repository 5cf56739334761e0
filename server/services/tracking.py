"""The spaces' trackers: detections in, live targets out (spec 08's pipeline, service side).

`ingest` stores a batch of detections (the detections table, committed before it returns) and
queues them, one camera frame (camera, capture time) at a time, for the tracker of the
cameras' space, with the frames in which the senders detected nothing (not stored). A
background thread releases the queued frames in time order once they are `latency` seconds
old, or sooner once every camera heard from has delivered frames as recent (so that cameras
whose batches arrive out of step still reach the tracker in order), feeds them to
core.localization.tracking.Tracker, and hands its reports to the live targets store. It keeps
the delays of the frames' stages (`delays`) and logs them when it stops. It also moves each
tracker's clock on when no frame comes, so silent tracks coast and end on time. The
association and filtering are all in core; this module only moves frames and results.

Several processes on one PostgreSQL database (`shared_database_url`): each space's tracker runs
in the one process that holds the space's advisory lock (server.services.ownership). A process
that stores detections of a space it does not track sends the others the camera frames it
took, with their stored rows' ids (LISTEN/NOTIFY, server.services.fanout; a frame too large for
one notification goes by its rows' ids alone, and is read back); the owner feeds them to its
tracker without reading the database, and sends every target change to the others, whose live
targets show it. The processes
try for free locks every `_OWNERSHIP_POLL_S`; one that gets a space (its owner died, and
PostgreSQL freed the lock with its connection) restores the space's tracks from what it last
heard of them (or, failing that, from the stored targets), keeping their ids
(core Tracker.restore), then replays the space's detections stored since.

On a shared database the core trackers themselves run in a child process of their own
(`_TrackerHost`), one per service process, which the tracker thread calls with each frame and
waits on: the tracker's arithmetic (milliseconds of Python and numpy per frame) then no longer
holds this process's interpreter lock, which its event loop (readers, posts, the WebSocket
streams) needs at the same time. Everything else (reorder buffers, the clock, publishing,
ownership) stays here; the child only does what core Tracker does.

Times are Unix seconds on the service's clock.
"""

from __future__ import annotations

import itertools
import json
import logging
import multiprocessing
import pickle
import re
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy import insert, or_, select
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
from server.db.models import Camera, Detection, Target
from server.delays import StageDelays
from server.services.fanout import PAYLOAD_LIMIT, Fanout
from server.services.ownership import SpaceLocks
from server.services.targets import LIVE, LiveTarget, LiveTargets

log = logging.getLogger(__name__)

# How often the tracker thread wakes (s), and how often it reloads the cameras' calibration.
_TICK_S = 0.02
_CAMERAS_RELOAD_S = 1.0
# Between processes: how often a process tries for the free spaces' locks (s); the channels.
_OWNERSHIP_POLL_S = 1.0
TARGETS_CHANNEL = "intspace_targets"
DETECTIONS_CHANNEL = "intspace_detections"
CONTROL_CHANNEL = "intspace_tracker_control"
# A space taken over: stored detections replayed (s before now at most, and how many), when
# there are no tracks to restore the last _REPLAY_FRESH_S; stored targets older than
# _RESTORE_S are not restored (a labelled track waits 60 s for its label, the others 5 s).
_REPLAY_MAX_S = 10.0
_REPLAY_FRESH_S = 2.0
_REPLAY_LIMIT = 50_000
_RESTORE_S = 60.0
# Detection ids a tracker remembers having been fed (one frame may reach it twice around a
# takeover: from the replay and from its notification).
_FED_IDS = 200_000
# Ids per query when reading notified detections.
_RUNS_PER_QUERY = 200


@dataclass(frozen=True)
class DetectionIn:
    """One detection to ingest: camera id, capture time (s), distorted pixel (2,), its 2x2
    covariance px^2, kind, height (m) of the measured point, label or None; a detector's box
    (x0, y0, x1, y1), score and cut sides when it came as a box, and whether it measures a
    floor position (`tracked` False: a box whose bottom is cut, stored only)."""

    camera_id: int
    t: float
    pixel: tuple[float, float]
    cov: tuple[tuple[float, float], tuple[float, float]]
    kind: str
    height: float
    label: str | None = None
    box: tuple[float, float, float, float] | None = None
    score: float | None = None
    cut: tuple[str, ...] | None = None
    tracked: bool = True


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
    ids: tuple[int, ...] = ()


@dataclass(frozen=True)
class IngestResult:
    """What `ingest` did: detections stored, camera frames queued, frames refused as late."""

    stored: int
    frames: int
    late: int


class FrameDelays(StageDelays):
    """The delays (s) of the camera frames a tracker processed, the newest `keep`: from capture
    to arrival at the service (the sender's detection and upload, or the twin's rendering and
    detection), arrival to release by the reorder buffer, and release to the end of the
    tracker's update and the live targets' change."""

    def __init__(self, keep: int = 20_000) -> None:
        super().__init__(("capture to arrival", "reorder wait", "tracker update"), keep)

    def frame(self, t: float, arrived: float, released: float, done: float) -> None:
        """Record one frame captured at t, arrived, released and processed at those times."""
        self.add(arrived - t, max(0.0, released - arrived), done - released)


def empty_frame(camera_id: int, t: float) -> CameraFrame:
    """Return a camera frame captured at `t` in which nothing was detected."""
    return CameraFrame(camera_id, t, np.zeros((0, 2)), np.zeros((0, 2, 2)), np.zeros(0), [], [])


def camera_frames(
    detections: Sequence[DetectionIn], ids: Sequence[int] | None = None
) -> list[CameraFrame]:
    """Return the detections split into camera frames (same camera and capture time), in time
    order; `ids` (one per detection) are their stored rows' ids, when known."""
    by_frame: dict[tuple[int, float], list[DetectionIn]] = {}
    row_ids: dict[tuple[int, float], list[int]] = {}
    for k, d in enumerate(detections):
        by_frame.setdefault((d.camera_id, d.t), []).append(d)
        if ids is not None:
            row_ids.setdefault((d.camera_id, d.t), []).append(int(ids[k]))
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
                ids=tuple(row_ids.get((camera_id, t), ())),
            )
        )
    return frames


# A camera frame sent to the space's tracker in another process is sent whole when its
# notification item stays below this many bytes (else by its rows' ids, read back there).
_FRAME_ITEM_BYTES = PAYLOAD_LIMIT - 200


def _frame_item(f: CameraFrame) -> dict[str, Any] | None:
    """Return a camera frame as a notification item: {"c": camera, "t": time} for an empty
    frame, with its stored rows' "ids", pixels, covariances (xx, xy, yy), heights, kinds and
    labels for the others; None when it is too large for one notification."""
    item: dict[str, Any] = {"c": f.camera_id, "t": f.t}
    if not f.pixels.shape[0]:
        return item
    item.update(
        ids=list(f.ids),
        px=f.pixels.tolist(),
        cov=f.cov.reshape(-1, 4)[:, [0, 1, 3]].tolist(),
        h=f.heights.tolist(),
        k=list(f.kinds),
        l=list(f.labels),
    )
    if len(json.dumps(item, separators=(",", ":"))) > _FRAME_ITEM_BYTES:
        return None
    return item


def _frame_of_item(item: dict[str, Any]) -> CameraFrame:
    """Return the camera frame of a notification item (`_frame_item`)."""
    if "px" not in item:
        return empty_frame(int(item["c"]), float(item["t"]))
    c = np.asarray(item["cov"], dtype=np.float64).reshape(-1, 3)
    cov = np.stack([c[:, [0, 1]], c[:, [1, 2]]], axis=1)
    return CameraFrame(
        camera_id=int(item["c"]),
        t=float(item["t"]),
        pixels=np.asarray(item["px"], dtype=np.float64).reshape(-1, 2),
        cov=cov,
        heights=np.asarray(item["h"], dtype=np.float64),
        kinds=[str(k) for k in item["k"]],
        labels=[None if v is None else str(v) for v in item["l"]],
        ids=tuple(int(i) for i in item["ids"]),
    )


def _id_runs(ids: Sequence[int]) -> list[list[int]]:
    """Return the sorted ids as runs [first, last] of consecutive ids."""
    runs: list[list[int]] = []
    for i in sorted(set(ids)):
        if runs and i == runs[-1][1] + 1:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    return runs


# What a tracker in the trackers' process may be asked (core Tracker's methods).
_TRACKER_CALLS = frozenset({"set_camera", "update", "advance", "shift", "restore", "tracks"})


def _serve_trackers(conn: Any) -> None:
    """Run core trackers for a TrackingService (its trackers' process, `_TrackerHost`): answer
    each request (key, op, args, kwargs) with (True, value, clock, tracks) of the tracker
    `key` after it, or (False, exception, None, 0); stop on None or when the parent is gone."""
    trackers: dict[int, Tracker] = {}
    while True:
        try:
            request = conn.recv()
        except (EOFError, OSError):
            return
        if request is None:
            return
        key, op, args, kwargs = request
        try:
            value: Any = None
            if op == "new":
                trackers[key] = Tracker(*args, **kwargs)
            elif op == "drop":
                trackers.pop(key, None)
            elif op == "occluders":
                trackers[key].occluders = args[0]
            elif op in _TRACKER_CALLS:
                value = getattr(trackers[key], op)(*args, **kwargs)
            else:
                raise ValueError(f"unknown tracker call {op!r}")
            tracker = trackers.get(key)
            answer = (
                True,
                value,
                None if tracker is None else tracker.time,
                0 if tracker is None else len(tracker),
            )
        except Exception as exc:
            answer = (False, _portable(exc), None, 0)
        try:
            conn.send(answer)
        except (EOFError, OSError):
            return
        except Exception as exc:  # an answer that does not pickle
            conn.send((False, RuntimeError(f"tracker call {op!r}: {exc}"), None, 0))


def _portable(exc: Exception) -> Exception:
    """Return `exc` if it survives pickling (core's typed errors do), else a RuntimeError that
    names it."""
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:
        return RuntimeError(f"{type(exc).__name__}: {exc}")
    return exc


class TrackerProcessError(RuntimeError):
    """The trackers' process stopped answering (it died or was stopped)."""


class _TrackerHost:
    """The child process that runs a TrackingService's core trackers (module docstring). It is
    forked from multiprocessing's fork server, which has this module imported already, so a
    host starts in milliseconds once the first has. Calls from several threads are served one
    at a time."""

    def __init__(self) -> None:
        context = multiprocessing.get_context("forkserver")
        context.set_forkserver_preload([__name__])
        conn, child = context.Pipe()
        self._conn: Any = conn
        self.process = context.Process(
            target=_serve_trackers, args=(child,), name="intspace-trackers", daemon=True
        )
        self.process.start()
        child.close()
        self._lock = threading.Lock()
        self._keys = itertools.count(1)

    def new_key(self) -> int:
        """Return a key no tracker of this host has had."""
        return next(self._keys)

    def call(self, key: int, op: str, *args: Any, **kwargs: Any) -> tuple[Any, float | None, int]:
        """Run `op` on tracker `key`; return (its value, the tracker's clock, its tracks). The
        tracker's own errors are raised here; TrackerProcessError when the process is gone."""
        with self._lock:
            if self._conn is None:
                raise TrackerProcessError("the trackers' process was stopped")
            try:
                self._conn.send((key, op, args, kwargs))
                ok, value, clock, n = self._conn.recv()
            except (EOFError, OSError) as exc:
                raise TrackerProcessError(
                    f"the trackers' process (pid {self.process.pid}) stopped answering: {exc!r}"
                ) from exc
        if not ok:
            raise value
        return value, clock, n

    def close(self) -> None:
        """Stop the process (its trackers are lost)."""
        with self._lock:
            if self._conn is not None:
                try:
                    self._conn.send(None)
                except OSError:
                    pass
                self._conn.close()
                self._conn = None
        self.process.join(5)
        if self.process.is_alive():
            self.process.kill()
            self.process.join(5)


class _RemoteTracker:
    """A core Tracker run by a `_TrackerHost`: the part of Tracker's interface the service
    uses, each call a round trip. Its clock and size are those of the last answer (the
    service's tracker thread is the only one that moves it, under the space's lock)."""

    def __init__(
        self, host: _TrackerHost, config: TrackerConfig, next_id: int, occluders: Occluders | None
    ) -> None:
        self._host = host
        self._key = host.new_key()
        self.cameras: dict[Hashable, NetworkCamera] = {}
        self._occluders = occluders
        self._time: float | None = None
        self._n = 0
        self._call("new", config=config, next_id=next_id, occluders=occluders)

    def _call(self, op: str, *args: Any, **kwargs: Any) -> Any:
        value, self._time, self._n = self._host.call(self._key, op, *args, **kwargs)
        return value

    @property
    def time(self) -> float | None:
        return self._time

    def __len__(self) -> int:
        return self._n

    @property
    def occluders(self) -> Occluders | None:
        return self._occluders

    @occluders.setter
    def occluders(self, occluders: Occluders | None) -> None:
        self._call("occluders", occluders)
        self._occluders = occluders

    def set_camera(self, key: Hashable, camera: NetworkCamera) -> None:
        self._call("set_camera", key, camera)
        self.cameras[key] = camera

    def update(self, camera: Hashable, t: float, *args: Any, **kwargs: Any) -> FrameResult:
        result: FrameResult = self._call("update", camera, t, *args, **kwargs)
        return result

    def advance(self, t: float) -> tuple[TrackSnapshot, ...]:
        ended: tuple[TrackSnapshot, ...] = self._call("advance", t)
        return ended

    def shift(self, dt: float) -> None:
        self._call("shift", dt)

    def restore(self, t: float, tracks: Sequence[TrackSnapshot]) -> tuple[TrackSnapshot, ...]:
        ended: tuple[TrackSnapshot, ...] = self._call("restore", t, list(tracks))
        return ended

    def tracks(
        self, t: float | None = None, *, states: Sequence[TrackState] | None = None
    ) -> tuple[TrackSnapshot, ...]:
        snaps: tuple[TrackSnapshot, ...] = self._call(
            "tracks", t, states=None if states is None else tuple(states)
        )
        return snaps

    def close(self) -> None:
        """Forget the tracker in the host (its space was reset or given up)."""
        try:
            self._call("drop")
        except TrackerProcessError:
            pass


class _SpaceTracker:
    """The tracker of one space (here, or in the trackers' process `host`), its reorder buffer
    and its cameras."""

    def __init__(
        self,
        space_id: int | None,
        config: TrackerConfig,
        latency: float,
        next_id: int,
        occluders: Occluders | None,
        host: _TrackerHost | None = None,
    ):
        self.space_id = space_id
        self.tracker: Tracker | _RemoteTracker
        if host is None:
            self.tracker = Tracker(config=config, next_id=next_id, occluders=occluders)
        else:
            self.tracker = _RemoteTracker(host, config, next_id, occluders)
        self.buffer = ReorderBuffer(latency=latency)
        self.cameras_loaded = -float("inf")
        self.refused: dict[int, str] = {}
        self.states: dict[int, TrackState] = {}
        # Held while the tracker thread changes the tracker, so readers see a whole state.
        self.lock = threading.RLock()
        # Service time at which the space's world was held still (the twin paused), or None.
        self.held_since: float | None = None
        self.fed: OrderedDict[int, None] = OrderedDict()

    def close(self) -> None:
        """Let the tracker go (the space was reset or given up)."""
        if isinstance(self.tracker, _RemoteTracker):
            self.tracker.close()

    def fresh(self, ids: tuple[int, ...]) -> bool:
        """Whether a frame of stored detections `ids` is new to this tracker (and remember it);
        a frame without ids (not stored by id) always is."""
        if not ids:
            return True
        if ids[0] in self.fed:
            return False
        for i in ids:
            self.fed[i] = None
        while len(self.fed) > _FED_IDS:
            self.fed.popitem(last=False)
        return True


class TrackingService:
    """One tracker per space, fed by `ingest`, run by one background thread. With
    `shared_database_url` (PostgreSQL), the processes sharing that database share the spaces'
    trackers (module docstring). With `separate_process` (by default: on a shared database)
    the core trackers run in a child process (`_TrackerHost`), started with the first space."""

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
        self._factory = factory
        if separate_process is None:
            separate_process = shared_database_url is not None
        self.separate_process = bool(separate_process)
        self._host: _TrackerHost | None = None
        self._host_lock = threading.Lock()
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
        # Called on the tracker thread with (space id, confirmed or coasting snapshots a frame
        # updated, snapshots of the live targets that ended): the zones (server.services.
        # zones). They must not block.
        self.target_listeners: list[
            Callable[[int | None, tuple[TrackSnapshot, ...], tuple[TrackSnapshot, ...]], None]
        ] = []
        self.delays = FrameDelays()
        self._fanout: Fanout | None = None
        self._locks: SpaceLocks | None = None
        # (space, [[first id, last id] of stored detections, or {"c": camera, "t": time} of
        # an empty frame, ...]) that other processes took for a space tracked here.
        self._notified: list[tuple[int | None, list[Any]]] = []
        self._notified_lock = threading.Lock()
        # Held while spaces are taken over or given up; the spaces tried for at least once.
        self._ownership_lock = threading.RLock()
        self._tried: set[int | None] = set()
        # Set when notifications may have been missed (the listener reconnected).
        self._resync = threading.Event()
        if shared_database_url is not None:
            self._fanout = Fanout(shared_database_url)
            self._locks = SpaceLocks(shared_database_url)
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
            }
            for d in detections
        ]
        ids: list[int] | None = None
        if self._locks is not None:
            # The rows' ids tell the space's tracker, maybe in another process, what to read.
            stmt = insert(Detection).returning(Detection.id, sort_by_parameter_order=True)
            ids = list(session.scalars(stmt, rows))
        else:
            session.execute(Detection.__table__.insert(), rows)
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

    def submit(self, frames: Sequence[CameraFrame], space_of: dict[int, int | None]) -> int:
        """Queue camera frames for their spaces' trackers; return how many came too late (older
        than what the tracker already processed)."""
        late = 0
        arrived = self._clock()
        elsewhere: dict[int | None, list[Any]] = {}
        if self._locks is not None:
            # A space never tried for is tried for at once: its first frames need not wait
            # for the next poll.
            for space_id in {space_of.get(f.camera_id) for f in frames} - self._tried:
                self._claim([space_id])
        with self._lock:
            for f in frames:
                space_id = space_of.get(f.camera_id)
                space = self._space(space_id)
                if space is None:
                    # Frames travel as themselves (with their rows' ids); one too large for a
                    # notification by its rows' ids, which the space's tracker reads back.
                    item = _frame_item(f)
                    mark = [item] if item is not None else list(f.ids)
                    elsewhere.setdefault(space_id, []).extend(mark)
                elif space.fresh(f.ids) and not space.buffer.push(
                    f.t, (f, arrived), source=f.camera_id, arrived=arrived
                ):
                    late += 1
        self._wake.set()
        if self._fanout is not None:
            for space_id, items in elsewhere.items():
                ids = [i for i in items if not isinstance(i, dict)]
                marks = [i for i in items if isinstance(i, dict)]
                self._fanout.publish(DETECTIONS_CHANNEL, {"space": space_id}, _id_runs(ids) + marks)
        return late

    def _space(self, space_id: int | None) -> _SpaceTracker | None:
        """Return the tracker of a space (made on first use), None when another process
        runs it (shared database). Call with self._lock held."""
        space = self._spaces.get(space_id)
        if space is None and self._locks is None:
            space = self._new_space(space_id)
            self._spaces[space_id] = space
        return space

    def _new_space(self, space_id: int | None) -> _SpaceTracker:
        with self._factory() as session:
            next_id = self._live.next_track_id(session, space_id)
        occluders = self._occluders.get(space_id)
        host = self._tracker_host() if self.separate_process else None
        return _SpaceTracker(space_id, self.config, self.latency, next_id, occluders, host)

    def _tracker_host(self) -> _TrackerHost:
        """Return the trackers' process, started on first use."""
        with self._host_lock:
            if self._host is None:
                self._host = _TrackerHost()
            return self._host

    def _recover(self) -> None:
        """The trackers' process died: start another and take the spaces tracked here over
        again, as from a process that died (their tracks restored from what was last stored,
        keeping their ids; the detections stored since replayed). Tracks not restored end."""
        with self._host_lock:
            host, self._host = self._host, None
        pid = None if host is None else host.process.pid
        log.error("the trackers' process (pid %s) died; starting another", pid)
        if host is not None:
            host.close()
        with self._ownership_lock:
            with self._lock:
                spaces = dict(self._spaces)
            for space_id, old in spaces.items():
                self._take_over(space_id)
                with self._lock:
                    new = self._spaces.get(space_id)
                kept = set() if new is None else set(new.states)
                for track_id in set(old.states) - kept:
                    self._live.end(space_id, track_id)

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

    def hold(self, space_id: int | None) -> None:
        """Hold a space's tracks still: its world is paused (the twin), so no frame comes and
        its tracks must neither coast nor end until `release`."""
        with self._lock:
            space = self._space(space_id)
        if space is None:
            self._forward(space_id, "hold")
            return
        with space.lock:
            if space.held_since is None:
                space.held_since = self._clock()

    def release(self, space_id: int | None) -> None:
        """Let a held space's tracks go on: their clock moves on by the time held."""
        with self._lock:
            space = self._space(space_id)
        if space is None:
            self._forward(space_id, "release")
            return
        with space.lock:
            if space.held_since is not None:
                space.tracker.shift(max(0.0, self._clock() - space.held_since))
                space.held_since = None

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
        self._stop.clear()
        if self._fanout is not None:
            self._live.publishing = True
            self._fanout.start()
        self._thread = threading.Thread(target=self._loop, name="tracker", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the tracker thread; on a shared database give the spaces up to the others."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
            self._thread = None
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
        while not self._stop.is_set():
            self._wake.wait(_TICK_S)
            self._wake.clear()
            try:
                if self._locks is not None:
                    beat = time.monotonic() - last_poll >= _OWNERSHIP_POLL_S
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
                for _, (frame, arrived) in frames:
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
        with self._live.batch():
            self._publish_frame(space, result)

    def _publish_frame(self, space: _SpaceTracker, result: FrameResult) -> None:
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

    def _publish_ended(self, space: _SpaceTracker, ended: tuple[TrackSnapshot, ...]) -> None:
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

    def _sync_states(self, space: _SpaceTracker) -> None:
        for snap in space.tracker.tracks(states=LIVE_STATES):
            if snap.id in space.states and space.states[snap.id] is not snap.state:
                space.states[snap.id] = snap.state
                self._live.set_state(space.space_id, snap.id, str(snap.state))

    # -- between processes -----------------------------------------------------------------

    def _on_targets(self, message: dict[str, Any]) -> None:
        """Show the target changes another process's trackers sent (listener thread)."""
        with self._lock:
            mine = set(self._spaces)
        if message.get("live"):
            if message.get("space") not in mine:
                self._live.retain_remote(message.get("space"), set(message.get("items", ())))
            return
        items = [i for i in message.get("items", ()) if i.get("space") not in mine]
        self._live.apply_remote(items)

    def _on_detections(self, message: dict[str, Any]) -> None:
        """Queue the camera frames another process took (or the ids of the detections it
        stored), listener thread."""
        with self._notified_lock:
            self._notified.append((message.get("space"), list(message.get("items", ()))))
        self._wake.set()

    def _publish_changes(self) -> None:
        assert self._fanout is not None
        self._fanout.publish(TARGETS_CHANNEL, {}, self._live.drain_changes())

    def _publish_live(self) -> None:
        """Tell the others which targets of each space tracked here are live: a target they
        show that is not (its end was missed, or its process died and the new owner could not
        restore it) leaves their lists."""
        assert self._fanout is not None
        with self._lock:
            spaces = list(self._spaces)
        for space_id in spaces:
            ids = self._live.track_ids(space_id)
            self._fanout.publish(TARGETS_CHANNEL, {"space": space_id, "live": True}, ids or [0])

    def _read_notified(self) -> None:
        """Feed the notified camera frames (and the detections notified by id, read here)
        of the spaces tracked here to their trackers, in time order."""
        with self._notified_lock:
            batch, self._notified = self._notified, []
        if not batch:
            return
        runs_of: dict[int | None, list[Any]] = {}
        with self._lock:
            for space_id, items in batch:
                if space_id in self._spaces:
                    runs_of.setdefault(space_id, []).extend(items)
        for space_id, items in runs_of.items():
            runs = [i for i in items if not isinstance(i, dict)]
            frames = [_frame_of_item(i) for i in items if isinstance(i, dict)]
            for start in range(0, len(runs), _RUNS_PER_QUERY):
                part = runs[start : start + _RUNS_PER_QUERY]
                cond = or_(*(Detection.id.between(int(lo), int(hi)) for lo, hi in part))
                frames += self._stored_frames(space_id, cond)
            frames.sort(key=lambda f: (f.t, f.camera_id))
            if frames:
                self.submit(frames, {f.camera_id: space_id for f in frames})

    def _catch_up(self) -> None:
        """Read again the detections of the spaces tracked here that their trackers have not
        passed yet: notifications of some may have been lost (frames already fed are known by
        their ids and skipped)."""
        with self._lock:
            since = {sid: space.buffer.released for sid, space in self._spaces.items()}
        for space_id, released in since.items():
            start = max(released, self._clock() - _REPLAY_MAX_S)
            self._submit_stored(space_id, Detection.t > start, limit=_REPLAY_LIMIT)

    def _submit_stored(
        self, space_id: int | None, *conditions: Any, limit: int | None = None
    ) -> int:
        """Read stored detections of a space (conditions) and queue them for its tracker;
        return how many were read."""
        frames = self._stored_frames(space_id, *conditions, limit=limit)
        if frames:
            self.submit(frames, {f.camera_id: space_id for f in frames})
        return sum(len(f.ids) for f in frames)

    def _stored_frames(
        self, space_id: int | None, *conditions: Any, limit: int | None = None
    ) -> list[CameraFrame]:
        """Return the stored detections of a space (conditions) as camera frames."""
        same = Detection.space_id.is_(None) if space_id is None else Detection.space_id == space_id
        stmt = select(Detection).where(same, *conditions).order_by(Detection.t, Detection.id)
        with self._factory() as session:
            rows = session.scalars(stmt.limit(limit) if limit else stmt).all()
        if not rows:
            return []
        detections = [
            DetectionIn(
                camera_id=r.camera_id,
                t=r.t,
                pixel=(r.u, r.v),
                cov=((r.cxx, r.cxy), (r.cxy, r.cyy)),
                kind=r.kind,
                height=r.height,
                label=r.label,
            )
            for r in rows
        ]
        return camera_frames(detections, [r.id for r in rows])

    def _poll_ownership(self) -> None:
        """Try for the free spaces' locks; take over those acquired, let go of those lost."""
        with self._factory() as session:
            spaces = set(session.scalars(select(Camera.space_id).distinct()))
        self._claim(spaces)

    def _claim(self, spaces: Any) -> None:
        """Try for the locks of `spaces`; take over those acquired, let go of those lost."""
        assert self._locks is not None
        with self._ownership_lock:
            spaces = set(spaces)
            self._tried |= spaces
            acquired, lost = self._locks.poll(spaces)
            self._hand_over(acquired, lost)

    def _hand_over(self, acquired: set[int | None], lost: set[int | None]) -> None:
        for space_id in lost:
            with self._lock:
                gone = self._spaces.pop(space_id, None)
            if gone is not None:
                gone.close()
            self._live.disown(space_id)
            log.warning("space %s: tracker lock lost; another process takes it over", space_id)
        for space_id in sorted(acquired, key=lambda s: -1 if s is None else s):
            self._take_over(space_id)

    def _take_over(self, space_id: int | None) -> None:
        """Start the tracker of a space this process now owns: restore the live tracks another
        process followed (keeping their ids), then replay the detections stored since."""
        now = self._clock()
        seeds: dict[int, TrackSnapshot] = {}
        adopted = self._live.adopt(space_id)
        for v in adopted:
            if v.state in LIVE:
                seeds[v.track_id] = _snapshot_of(v, self.config)
        stored_only: list[LiveTarget] = []
        with self._factory() as session:
            for row in self._live.stored_live(session, space_id):
                tid = int(row.track_id or 0)
                if tid in seeds or tid < 1 or row.t is None or row.xy is None or row.cov is None:
                    continue
                if now - float(row.last_seen or row.t) > _RESTORE_S:
                    continue
                v = _live_of(row)
                stored_only.append(v)
                seeds[tid] = _snapshot_of(v, self.config)
        space = self._new_space(space_id)
        ended: tuple[TrackSnapshot, ...] = ()
        restored: list[TrackSnapshot] = []
        if seeds:
            t0 = max(s.t for s in seeds.values())
            try:
                ended = space.tracker.restore(t0, list(seeds.values()))
                restored = list(space.tracker.tracks(states=LIVE_STATES))
            except IntspaceError as exc:
                log.warning("space %s: its tracks could not be restored: %s", space_id, exc)
                space.close()
                space = self._new_space(space_id)
        for v in stored_only:
            if v.track_id in {s.id for s in restored}:
                self._live.seed(v)
        for snap in restored:
            space.states[snap.id] = snap.state
        for snap in ended:
            self._live.end(space_id, snap.id)
        kept = {s.id for s in restored} | {s.id for s in ended}
        for v in adopted:
            if v.track_id not in kept:
                self._live.end(space_id, v.track_id)  # not restorable: it ends here
        with self._lock:
            self._spaces[space_id] = space
        # Frames stored while the space had no tracker: from the restored tracks' time on.
        since = space.tracker.time if space.tracker.time is not None else now - _REPLAY_FRESH_S
        since = max(since, now - _REPLAY_MAX_S)
        replayed = self._submit_stored(space_id, Detection.t > since, limit=_REPLAY_LIMIT)
        with self._factory() as session:
            closed = self._live.close_stale_space(session, space_id, [s.id for s in restored])
        log.info(
            "space %s: tracker taken over (%d track(s) restored, %d ended, %d stale closed, "
            "%d detection(s) replayed)",
            space_id,
            len(restored),
            len(ended),
            closed,
            replayed,
        )
        self._wake.set()

    # -- reads -------------------------------------------------------------------------------

    def tracks(self, space_id: int | None) -> tuple[TrackSnapshot, ...]:
        """Return the live tracks of a space (confirmed and coasting)."""
        with self._lock:
            space = self._spaces.get(space_id)
        if space is None:
            return ()
        with space.lock:
            return space.tracker.tracks(states=LIVE_STATES)


# A target's name when no sender labelled it (LiveTargets.update): kind-space-track.
_AUTO_NAME = re.compile(r"(robot|person|unknown)-(\d+)-(\d+)")


def _live_of(row: Target) -> LiveTarget:
    """Return a stored live target as a LiveTarget (speed unknown)."""
    space = row.space_id if row.space_id is not None else 0
    auto = _AUTO_NAME.fullmatch(row.label)
    labelled = auto is None or (int(auto[2]), int(auto[3])) != (space, row.track_id)
    t = float(row.t or 0.0)
    v = LiveTarget(
        row.space_id,
        int(row.track_id or 0),
        row.label,
        row.kind,
        row.state,
        float(row.first_seen if row.first_seen is not None else t),
        float(row.last_seen if row.last_seen is not None else t),
        t,
        [float(c) for c in (row.xy or [0.0, 0.0])],
        [[float(c) for c in r] for r in (row.cov or [[1.0, 0.0], [0.0, 1.0]])],
    )
    v.id, v.labelled = row.id, labelled
    return v


def _snapshot_of(v: LiveTarget, config: TrackerConfig) -> TrackSnapshot:
    """Return a live target as the tracker's snapshot, for Tracker.restore: its full state
    covariance when its tracker sent it, else its position's with an unknown speed (zero,
    the prior's variance)."""
    if v.state_cov is not None:
        x = np.array([v.xy[0], v.xy[1], v.velocity[0], v.velocity[1]], dtype=np.float64)
        P = np.array(v.state_cov, dtype=np.float64)
    else:
        x = np.array([v.xy[0], v.xy[1], 0.0, 0.0], dtype=np.float64)
        P = np.zeros((4, 4))
        P[:2, :2] = np.array(v.cov, dtype=np.float64)
        P[2, 2] = P[3, 3] = config.initial_speed_std**2
    return TrackSnapshot(
        id=v.track_id,
        kind=v.kind,
        label=v.label if v.labelled else None,
        state=TrackState(v.state),
        t=v.t,
        x=x,
        cov=P,
        hits=max(v.hits, 1),
        first_seen=min(v.first_seen, v.last_seen),
        last_seen=min(v.last_seen, v.t),
    )
