"""Live targets: what the spaces' trackers follow, kept in memory for the stream and the scene,
and written to the database (targets with their life cycle, track points at the tracker's
rate) by a background thread, under a retention by time.

A target is one track of a space's tracker (core.localization.tracking), keyed by (space id,
track id). Its points are stored at most `track_hz` times a second, each with the time of the
observation that produced it; the ended ones leave memory once written. Track points and
detections older than their retention are deleted, as are ended targets not seen since.

Where several service processes share a PostgreSQL database, only the process that runs a
space's tracker (server.services.ownership) writes that space's targets; it hands every change
to the others (`drain_changes`, sent by server.services.fanout), which keep them in memory as
remote targets (`apply_remote`) for their own streams and never write them. A process that
takes a space over adopts its remote targets (`adopt`), keeping their ids.
"""

from __future__ import annotations

import copy
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, cast

from sqlalchemy import Table, delete, func, select, update
from sqlalchemy.orm import Session, sessionmaker

from server.db.base import utcnow
from server.db.models import Detection, Target, TrackPoint
from server.services._loop_thread import LoopThread
from server.services.jobs import rows_changed

log = logging.getLogger(__name__)

LIVE = ("confirmed", "coasting")
# In-memory track of each live target for the 3D scene and the floor page (points).
_MEMORY_POINTS = 600
# Targets written per transaction: a flood of targets must not hold SQLite's write lock for
# seconds (every other writer would fail with "database is locked").
FLUSH_CHUNK = 200


@dataclass
class LiveTarget:
    """One target's latest state and its recent track (t, x, y) in memory."""

    space_id: int | None
    track_id: int
    label: str
    kind: str
    state: str
    first_seen: float
    last_seen: float
    t: float
    xy: list[float]
    cov: list[list[float]]
    velocity: list[float] = field(default_factory=lambda: [0.0, 0.0])
    id: int | None = None
    track: deque[tuple[float, float, float]] = field(
        default_factory=lambda: deque(maxlen=_MEMORY_POINTS)
    )
    pending: list[tuple[float, list[float], list[list[float]]]] = field(default_factory=list)
    dirty: bool = True
    last_stored: float = -float("inf")
    labelled: bool = False
    # The tracker's full state covariance (4 x 4: x, y, vx, vy) and its number of updates,
    # what another process needs to take the track over.
    state_cov: list[list[float]] | None = None
    hits: int = 0
    # Followed by another process's tracker: shown, never written here.
    remote: bool = False


class LiveTargets:
    """Thread-safe store of the live targets of every space. `update`, `set_state` and `end`
    are cheap (memory only); `start` runs the writer thread that flushes every 1 / flush_hz
    seconds and applies the retention once a minute."""

    def __init__(
        self,
        factory: sessionmaker[Session],
        *,
        flush_hz: float = 2.0,
        track_hz: float = 20.0,
        track_retention_s: float = 86400.0,
        detection_retention_s: float = 3600.0,
        space_id: int | None = None,
    ) -> None:
        self._factory = factory
        self._period = 1.0 / flush_hz
        self._min_dt = 1.0 / track_hz
        self.track_retention_s = track_retention_s
        self.detection_retention_s = detection_retention_s
        self.space_id = space_id
        self._lock = threading.Lock()
        # One flush at a time: a flush returns only once everything pending when it was called
        # is committed, even when the writer thread took the batch a moment before.
        self._flush_lock = threading.Lock()
        self._targets: dict[tuple[int | None, int], LiveTarget] = {}
        self._ended: list[LiveTarget] = []
        self._runner = LoopThread(self._loop, "targets-writer", join_timeout=10)
        self._last_retention = 0.0
        self._watchers: list[Callable[[], None]] = []
        self._local = threading.local()
        self.version = 0
        # Set when other processes follow this one's targets: changes wait in the outbox.
        self.publishing = False
        self._outbox: dict[tuple[int | None, int], LiveTarget] = {}

    @property
    def version(self) -> int:
        """A number that grows with every change of the live targets."""
        return self._version

    @version.setter
    def version(self, value: int) -> None:
        self._version = value
        if getattr(self._local, "depth", 0):
            self._local.pending = True  # told once, when the batch ends
            return
        for notify in list(self._watchers):
            notify()

    @contextmanager
    def batch(self) -> Iterator[None]:
        """Within it, this thread's changes wake the watchers once, at its end (one tracker
        frame's tracks are one change for the streams, not one per track)."""
        depth = getattr(self._local, "depth", 0)
        self._local.depth = depth + 1
        try:
            yield
        finally:
            self._local.depth = depth
            if depth == 0 and getattr(self._local, "pending", False):
                self._local.pending = False
                for notify in list(self._watchers):
                    notify()

    def watch(self, notify: Callable[[], None]) -> Callable[[], None]:
        """Call `notify()` after every change (in the changing thread, with the store locked:
        it must return at once, e.g. wake an event loop); return what stops it."""
        self._watchers.append(notify)
        return lambda: self._watchers.remove(notify)

    # -- from the trackers -----------------------------------------------------------------------

    def update(
        self,
        space_id: int | None,
        track_id: int,
        *,
        label: str | None,
        kind: str,
        state: str,
        first_seen: float,
        t: float,
        xy: list[float],
        cov: list[list[float]],
        velocity: list[float] | None = None,
        state_cov: list[list[float]] | None = None,
        hits: int | None = None,
    ) -> None:
        """Record a new position of a track (its target is created on first sight);
        state_cov is the tracker's 4 x 4 covariance of (x, y, vx, vy), hits its updates."""
        key = (space_id, track_id)
        with self._lock:
            target = self._targets.get(key)
            if target is None:
                name = label or f"{kind}-{space_id if space_id is not None else 0}-{track_id}"
                target = LiveTarget(
                    space_id, track_id, name, kind, state, first_seen, t, t, xy, cov
                )
                target.labelled = label is not None
                self._targets[key] = target
            target.kind, target.state = kind, state
            target.t, target.xy, target.cov, target.last_seen = t, xy, cov, t
            if velocity is not None:
                target.velocity = velocity
            if state_cov is not None:
                target.state_cov = state_cov
            if hits is not None:
                target.hits = hits
            target.remote = False
            target.track.append((t, xy[0], xy[1]))
            if t - target.last_stored >= self._min_dt - 1e-9:
                target.pending.append((t, xy, cov))
                target.last_stored = t
            target.dirty = True
            self._changed(key, target)
            self.version += 1

    def set_state(self, space_id: int | None, track_id: int, state: str) -> None:
        """Record a track's new life cycle state (e.g. coasting)."""
        with self._lock:
            target = self._targets.get((space_id, track_id))
            if target is not None and target.state != state:
                target.state = state
                target.dirty = not target.remote
                self._changed((space_id, track_id), target)
                self.version += 1

    def end(self, space_id: int | None, track_id: int) -> None:
        """Record that a track ended: it leaves the live set once written."""
        with self._lock:
            target = self._targets.pop((space_id, track_id), None)
            if target is not None:
                target.state = "ended"
                if not target.remote:
                    target.dirty = True
                    self._ended.append(target)
                    self._changed((space_id, track_id), target)
                self.version += 1

    def end_space(self, space_id: int | None) -> None:
        """End every live target of a space (its tracker was reset)."""
        with self._lock:
            keys = [k for k in self._targets if k[0] == space_id]
        for key in keys:
            self.end(*key)

    # -- between processes ----------------------------------------------------------------------

    def _changed(self, key: tuple[int | None, int], target: LiveTarget) -> None:
        if self.publishing and not target.remote:
            self._outbox[key] = target

    def drain_changes(self) -> list[dict[str, Any]]:
        """Return (and forget) the targets changed here since the last call, as messages for
        the other processes (`apply_remote`); empty unless `publishing`."""
        with self._lock:
            changed, self._outbox = list(self._outbox.values()), {}
            return [_message(v) for v in changed]

    def apply_remote(self, items: list[dict[str, Any]]) -> int:
        """Show targets that another process's tracker follows (messages of its
        `drain_changes`); return how many changed. Targets this process follows are left
        alone."""
        changed = 0
        with self._lock:
            for item in items:
                key = (item["space"], int(item["track"]))
                target = self._targets.get(key)
                if target is not None and not target.remote:
                    continue
                if item["state"] == "ended":
                    if self._targets.pop(key, None) is not None:
                        changed += 1
                    continue
                if target is None:
                    target = LiveTarget(
                        key[0],
                        key[1],
                        item["label"],
                        item["kind"],
                        item["state"],
                        item["first_seen"],
                        item["last_seen"],
                        item["t"],
                        item["xy"],
                        item["cov"],
                    )
                    target.remote = True
                    self._targets[key] = target
                target.id = item["id"] if item["id"] is not None else target.id
                target.label, target.labelled = item["label"], bool(item["labelled"])
                target.kind, target.state = item["kind"], item["state"]
                target.first_seen, target.last_seen = item["first_seen"], item["last_seen"]
                target.t, target.xy, target.cov = item["t"], item["xy"], item["cov"]
                target.velocity, target.state_cov = item["velocity"], item["P"]
                target.hits = int(item["hits"])
                target.dirty = False
                if not target.track or target.track[-1][0] < target.t:
                    target.track.append((target.t, target.xy[0], target.xy[1]))
                changed += 1
            if changed:
                self.version += 1
        return changed

    def adopt(self, space_id: int | None) -> list[LiveTarget]:
        """Make the remote targets of a space this process's own (it now runs the space's
        tracker); return copies of them, to seed the tracker with."""
        out = []
        with self._lock:
            for (sid, _), v in self._targets.items():
                if sid == space_id and v.remote:
                    v.remote = False
                    v.dirty = True
                    v.last_stored = v.t  # the previous owner stored its points up to here
                    out.append(copy.copy(v))
        return out

    def track_ids(self, space_id: int | None) -> list[int]:
        """Return the track ids of the targets of a space followed here (not remote)."""
        with self._lock:
            return [k for (s, k), v in self._targets.items() if s == space_id and not v.remote]

    def retain_remote(self, space_id: int | None, track_ids: set[int]) -> int:
        """Drop the remote targets of a space whose tracker no longer follows them (not in
        `track_ids`); return how many went."""
        with self._lock:
            gone = [
                key
                for key, v in self._targets.items()
                if key[0] == space_id and v.remote and key[1] not in track_ids
            ]
            for key in gone:
                del self._targets[key]
            if gone:
                self.version += 1
        return len(gone)

    def seed(self, target: LiveTarget) -> None:
        """Follow a stored target again (a tracker that took its space over restored it): it
        is live here, with its stored id and name."""
        key = (target.space_id, target.track_id)
        with self._lock:
            if key in self._targets:
                return
            target.remote, target.dirty, target.last_stored = False, True, target.t
            target.track.append((target.t, target.xy[0], target.xy[1]))
            self._targets[key] = target
            self._changed(key, target)
            self.version += 1

    def disown(self, space_id: int | None) -> int:
        """Hand the targets of a space to whichever process runs its tracker now (this one
        lost it): they stay shown, as remote, until that process says otherwise."""
        with self._lock:
            mine = [v for (sid, _), v in self._targets.items() if sid == space_id and not v.remote]
            for v in mine:
                v.remote, v.dirty, v.pending = True, False, []
                self._outbox.pop((v.space_id, v.track_id), None)
        return len(mine)

    # -- reads -----------------------------------------------------------------------------------

    def snapshot(self) -> tuple[int, list[dict[str, Any]]]:
        """Return (version, live targets) with id, label, kind, state, t, xy, cov, first_seen."""
        with self._lock:
            items = [
                {
                    "id": v.id,
                    "space_id": v.space_id,
                    "label": v.label,
                    "kind": v.kind,
                    "state": v.state,
                    "t": v.t,
                    "xy": v.xy,
                    "cov": v.cov,
                    "velocity": v.velocity,
                    "first_seen": v.first_seen,
                    "last_seen": v.last_seen,
                }
                for v in self._targets.values()
            ]
            return self.version, items

    def track(self, label: str) -> list[list[float]]:
        """Return the in-memory track [[x, y], ...] of the live target `label` (oldest first)."""
        with self._lock:
            for target in self._targets.values():
                if target.label == label:
                    return [[x, y] for _, x, y in target.track]
            return []

    def get(self, label: str) -> LiveTarget | None:
        """Return the live target called `label`, None when there is none."""
        with self._lock:
            return next((v for v in self._targets.values() if v.label == label), None)

    def latest(self, label: str) -> tuple[str, float, list[float]] | None:
        """Return the (state, t, xy) of the live target called `label`, read together (the
        trackers update it meanwhile), None when there is none."""
        with self._lock:
            v = next((v for v in self._targets.values() if v.label == label), None)
            return None if v is None else (v.state, v.t, list(v.xy))

    def live_labels(self, space_id: int | None) -> set[str]:
        """Return the labels senders gave the live targets of a space."""
        with self._lock:
            return {
                v.label for (sid, _), v in self._targets.items() if sid == space_id and v.labelled
            }

    def __len__(self) -> int:
        with self._lock:
            return len(self._targets)

    # -- the writer ------------------------------------------------------------------------------

    def start(self) -> None:
        """Start the writer thread."""
        self._runner.start()

    def stop(self) -> None:
        """Stop the writer thread after a last flush."""
        self._runner.stop()
        self.flush()

    def _loop(self) -> None:
        while not self._runner.wait(self._period):
            try:
                self.flush()
                if time.monotonic() - self._last_retention > 60.0:
                    self._last_retention = time.monotonic()
                    self.apply_retention()
            except Exception:
                log.exception("writing targets failed")

    def flush(self) -> int:
        """Write the changed targets and their pending points; return the points written."""
        with self._flush_lock:
            return self._flush()

    def _flush(self) -> int:
        with self._lock:
            batch = [v for v in self._targets.values() if v.dirty and not v.remote] + self._ended
            self._ended = []
            work = []
            for v in batch:
                work.append(
                    (
                        v,
                        v.pending,
                        (v.state, v.t, v.xy, v.cov, v.first_seen, v.last_seen, v.kind),
                    )
                )
                v.pending = []
                v.dirty = False
        known = {id(v) for v, _, _ in work if v.id is not None}
        written = 0
        for start in range(0, len(work), FLUSH_CHUNK):
            written += self._write(work[start : start + FLUSH_CHUNK])
        if self.publishing:
            # The other processes learn the new targets' database ids.
            with self._lock:
                for v, _, _ in work:
                    if id(v) not in known and v.state != "ended":
                        self._changed((v.space_id, v.track_id), v)
        return written

    def _write(self, work: list[Any]) -> int:
        """Write one chunk of targets and their points in one short transaction."""
        written = 0
        with self._factory() as session:
            for live, points, (state, t, xy, cov, first, last, kind) in work:
                row = session.get(Target, live.id) if live.id is not None else None
                if row is None:
                    row = session.scalar(select(Target).where(Target.label == live.label))
                if row is None:
                    row = Target(label=live.label, space_id=live.space_id, first_seen=first)
                    session.add(row)
                row.kind, row.state, row.track_id = kind, state, live.track_id
                row.t, row.xy, row.cov, row.last_seen = t, xy, cov, last
                if row.first_seen is None:
                    row.first_seen = first
                row.updated_at = utcnow()
                session.flush()
                live.id = row.id
                if points:
                    session.execute(
                        cast(Table, TrackPoint.__table__).insert(),
                        [
                            {"target_id": row.id, "t": pt, "x": pxy[0], "y": pxy[1], "cov": pcov}
                            for pt, pxy, pcov in points
                        ],
                    )
                    written += len(points)
            session.commit()
        return written

    def apply_retention(self, now: float | None = None) -> dict[str, int]:
        """Delete track points, detections and ended targets older than their retention;
        return how many rows of each went."""
        now = time.time() if now is None else now
        track_cut = now - self.track_retention_s
        det_cut = now - self.detection_retention_s
        with self._factory() as session:
            points = rows_changed(
                session.execute(delete(TrackPoint).where(TrackPoint.t < track_cut))
            )
            dets = rows_changed(session.execute(delete(Detection).where(Detection.t < det_cut)))
            old = select(Target.id).where(Target.state == "ended", Target.last_seen < track_cut)
            ids = list(session.scalars(old))
            if ids:
                session.execute(delete(TrackPoint).where(TrackPoint.target_id.in_(ids)))
                session.execute(delete(Target).where(Target.id.in_(ids)))
            session.commit()
        return {"track_points": points or 0, "detections": dets or 0, "targets": len(ids)}

    def close_stale(self, session: Session) -> int:
        """Mark targets left live by an earlier run of the service as ended; return how many.
        Their trackers' state did not survive the restart."""
        result = session.execute(update(Target).where(Target.state.in_(LIVE)).values(state="ended"))
        session.commit()
        return rows_changed(result)

    def close_stale_space(self, session: Session, space_id: int | None, keep: list[int]) -> int:
        """Mark the stored live targets of one space as ended but those whose track ids are in
        `keep` (the tracker that takes the space over goes on with those); return how many."""
        stmt = update(Target).where(Target.state.in_(LIVE), _same_space(space_id))
        if keep:
            stmt = stmt.where(Target.track_id.is_(None) | Target.track_id.not_in(keep))
        result = session.execute(stmt.values(state="ended"))
        session.commit()
        return rows_changed(result)

    def stored_live(self, session: Session, space_id: int | None) -> list[Target]:
        """Return the stored live targets of a space that have a track id."""
        stmt = select(Target).where(
            _same_space(space_id), Target.state.in_(LIVE), Target.track_id.is_not(None)
        )
        return list(session.scalars(stmt))

    def next_track_id(self, session: Session, space_id: int | None) -> int:
        """Return the first track id a new tracker of `space_id` may use (after the stored and
        those in memory)."""
        stmt = select(func.max(Target.track_id)).where(_same_space(space_id))
        stored = int(session.scalar(stmt) or 0)
        with self._lock:
            shown = max((k for s, k in self._targets if s == space_id), default=0)
        return max(stored, shown) + 1


def _same_space(space_id: int | None) -> Any:
    return Target.space_id.is_(None) if space_id is None else Target.space_id == space_id


def _message(v: LiveTarget) -> dict[str, Any]:
    """Return the fan-out message of a target (see LiveTargets.apply_remote)."""
    return {
        "space": v.space_id,
        "track": v.track_id,
        "id": v.id,
        "label": v.label,
        "labelled": v.labelled,
        "kind": v.kind,
        "state": v.state,
        "first_seen": v.first_seen,
        "last_seen": v.last_seen,
        "t": v.t,
        "xy": v.xy,
        "cov": v.cov,
        "velocity": v.velocity,
        "P": v.state_cov,
        "hits": v.hits,
    }
