"""The core trackers in a child process of their own: on a shared database a TrackingService
runs them there, one child per service process, so that the trackers' arithmetic (milliseconds
of Python and numpy per frame) no longer holds the service's interpreter lock, which its event
loop needs at the same time. `TrackerHost` is the child, `serve_trackers` what it runs, and
`RemoteTracker` the part of core Tracker's interface the service uses, each call a round trip.
The child only does what core Tracker does."""

from __future__ import annotations

import itertools
import multiprocessing
import pickle
import threading
from collections.abc import Hashable, Sequence
from typing import Any

from core.localization import NetworkCamera, Occluders
from core.localization.tracking import (
    FrameResult,
    Tracker,
    TrackerConfig,
    TrackSnapshot,
    TrackState,
)

# What a tracker in the trackers' process may be asked (core Tracker's methods).
_TRACKER_CALLS = frozenset({"set_camera", "update", "advance", "shift", "restore", "tracks"})


def serve_trackers(conn: Any) -> None:
    """Run core trackers for a TrackingService (its trackers' process, `TrackerHost`): answer
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


class TrackerHost:
    """The child process that runs a TrackingService's core trackers. It is forked from
    multiprocessing's fork server, which has this module imported already, so a host starts in
    milliseconds once the first has. Calls from several threads are served one at a time."""

    def __init__(self) -> None:
        context = multiprocessing.get_context("forkserver")
        context.set_forkserver_preload([__name__])
        conn, child = context.Pipe()
        self._conn: Any = conn
        self.process = context.Process(
            target=serve_trackers, args=(child,), name="intspace-trackers", daemon=True
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


class RemoteTracker:
    """A core Tracker run by a `TrackerHost`: the part of Tracker's interface the service
    uses, each call a round trip. Its clock and size are those of the last answer (the
    service's tracker thread is the only one that moves it, under the space's lock)."""

    def __init__(
        self, host: TrackerHost, config: TrackerConfig, next_id: int, occluders: Occluders | None
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
