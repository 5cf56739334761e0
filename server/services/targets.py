"""Live targets: what the spaces' trackers follow, kept in memory for the stream and the scene,
and written to the database (targets with their life cycle, track points at the tracker's
rate) by a background thread, under a retention by time.

A target is one track of a space's tracker (core.localization.tracking), keyed by (space id,
track id). Its points are stored at most `track_hz` times a second, each with the time of the
observation that produced it; the ended ones leave memory once written. Track points and
detections older than their retention are deleted, as are ended targets not seen since.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from sqlalchemy import delete, func, select, update
from sqlalchemy.orm import Session, sessionmaker

from server.db.base import utcnow
from server.db.models import Detection, Target, TrackPoint

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
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._last_retention = 0.0
        self.version = 0

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
    ) -> None:
        """Record a new position of a track (its target is created on first sight)."""
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
            target.track.append((t, xy[0], xy[1]))
            if t - target.last_stored >= self._min_dt - 1e-9:
                target.pending.append((t, xy, cov))
                target.last_stored = t
            target.dirty = True
            self.version += 1

    def set_state(self, space_id: int | None, track_id: int, state: str) -> None:
        """Record a track's new life cycle state (e.g. coasting)."""
        with self._lock:
            target = self._targets.get((space_id, track_id))
            if target is not None and target.state != state:
                target.state = state
                target.dirty = True
                self.version += 1

    def end(self, space_id: int | None, track_id: int) -> None:
        """Record that a track ended: it leaves the live set once written."""
        with self._lock:
            target = self._targets.pop((space_id, track_id), None)
            if target is not None:
                target.state = "ended"
                target.dirty = True
                self._ended.append(target)
                self.version += 1

    def end_space(self, space_id: int | None) -> None:
        """End every live target of a space (its tracker was reset)."""
        with self._lock:
            keys = [k for k in self._targets if k[0] == space_id]
        for key in keys:
            self.end(*key)

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
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name="targets-writer", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the writer thread after a last flush."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
            self._thread = None
        self.flush()

    def _loop(self) -> None:
        while not self._stop.wait(self._period):
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
            batch = [v for v in self._targets.values() if v.dirty] + self._ended
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
        written = 0
        for start in range(0, len(work), FLUSH_CHUNK):
            written += self._write(work[start : start + FLUSH_CHUNK])
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
                        TrackPoint.__table__.insert(),
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
            points = session.execute(delete(TrackPoint).where(TrackPoint.t < track_cut)).rowcount
            dets = session.execute(delete(Detection).where(Detection.t < det_cut)).rowcount
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
        return result.rowcount or 0

    def next_track_id(self, session: Session, space_id: int | None) -> int:
        """Return the first track id a new tracker of `space_id` may use (after the stored)."""
        stmt = select(func.max(Target.track_id)).where(Target.space_id == space_id)
        return int(session.scalar(stmt) or 0) + 1
