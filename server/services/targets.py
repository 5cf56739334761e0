"""Live targets: the latest position of everything the network locates, kept in memory for the
stream and the scene, and written to the database (targets + track points) by a background
thread at a throttled rate with a bounded history per target."""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from sqlalchemy import delete, select
from sqlalchemy.orm import Session, sessionmaker

from server.db.base import utcnow
from server.db.models import Target, TrackPoint

log = logging.getLogger(__name__)


@dataclass
class LiveTarget:
    """One target's latest state and its recent track (t, x, y) in memory."""

    label: str
    kind: str
    t: float
    xy: list[float]
    cov: list[list[float]]
    id: int | None = None
    seen_at: float = 0.0
    track: deque[tuple[float, float, float]] = field(default_factory=lambda: deque(maxlen=600))
    pending: list[tuple[float, list[float], list[list[float]]]] = field(default_factory=list)


class LiveTargets:
    """Thread-safe store of live targets. `update` is cheap (memory only); `start` runs the
    writer thread that flushes the latest point of each target every 1 / flush_hz seconds and
    keeps at most `history` track points per target in the database."""

    def __init__(
        self,
        factory: sessionmaker[Session],
        *,
        flush_hz: float = 1.0,
        history: int = 2000,
        space_id: int | None = None,
    ) -> None:
        self._factory = factory
        self._period = 1.0 / flush_hz
        self._history = history
        self.space_id = space_id
        self._lock = threading.Lock()
        self._targets: dict[str, LiveTarget] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.version = 0

    def update(self, label: str, kind: str, t: float, xy: list[float], cov: list[list[float]]):
        """Record a new position of target `label` (created on first sight)."""
        with self._lock:
            target = self._targets.get(label)
            if target is None:
                target = LiveTarget(label, kind, t, xy, cov)
                self._targets[label] = target
            target.t, target.xy, target.cov = t, xy, cov
            target.seen_at = time.monotonic()
            target.track.append((t, xy[0], xy[1]))
            # Only the newest point waits for the writer: the database history is throttled.
            target.pending = [(t, xy, cov)]
            self.version += 1

    def snapshot(self, max_age: float = 5.0) -> tuple[int, list[dict[str, Any]]]:
        """Return (version, targets) with id, label, kind, t, xy, cov of each target updated
        within the last `max_age` seconds (wall clock)."""
        oldest = time.monotonic() - max_age
        with self._lock:
            items = [
                {"id": v.id, "label": v.label, "kind": v.kind, "t": v.t, "xy": v.xy, "cov": v.cov}
                for v in self._targets.values()
                if v.seen_at >= oldest
            ]
            return self.version, items

    def track(self, label: str) -> list[list[float]]:
        """Return the in-memory track [[x, y], ...] of `label` (oldest first)."""
        with self._lock:
            target = self._targets.get(label)
            return [] if target is None else [[x, y] for _, x, y in target.track]

    def get(self, label: str) -> LiveTarget | None:
        """Return the live target called `label`, None when it was never seen."""
        with self._lock:
            return self._targets.get(label)

    def clear_tracks(self, kinds: tuple[str, ...]) -> None:
        """Forget the in-memory tracks of targets of `kinds` (the database keeps its history)."""
        with self._lock:
            for target in self._targets.values():
                if target.kind in kinds:
                    target.track.clear()
                    target.pending.clear()

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
            except Exception:
                log.exception("writing targets failed")

    def flush(self) -> int:
        """Write the pending points to the database; return how many were written."""
        with self._lock:
            batch = [(v, v.pending) for v in self._targets.values() if v.pending]
            for v, _ in batch:
                v.pending = []
        if not batch:
            return 0
        written = 0
        with self._factory() as session:
            for live, points in batch:
                row = session.get(Target, live.id) if live.id is not None else None
                if row is None:
                    row = session.scalar(select(Target).where(Target.label == live.label))
                if row is None:
                    row = Target(label=live.label, kind=live.kind, space_id=self.space_id)
                    session.add(row)
                    session.flush()
                t, xy, cov = points[-1]
                row.t, row.xy, row.cov, row.updated_at = t, xy, cov, utcnow()
                for t, xy, cov in points:
                    session.add(TrackPoint(target_id=row.id, t=t, x=xy[0], y=xy[1], cov=cov))
                    written += 1
                live.id = row.id
                self._prune(session, row.id)
            session.commit()
        return written

    def _prune(self, session: Session, target_id: int) -> None:
        oldest_kept = session.scalar(
            select(TrackPoint.id)
            .where(TrackPoint.target_id == target_id)
            .order_by(TrackPoint.id.desc())
            .offset(self._history - 1)
            .limit(1)
        )
        if oldest_kept is not None:
            session.execute(
                delete(TrackPoint).where(
                    TrackPoint.target_id == target_id, TrackPoint.id < oldest_kept
                )
            )
