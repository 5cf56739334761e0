"""Which process tracks each space, on a shared database (PostgreSQL, several processes): each
space's tracker runs in the one process that holds the space's advisory lock
(server.services.ownership). A process that stores detections of a space it does not track
sends the others the camera frames it took, with their stored rows' ids (LISTEN/NOTIFY,
server.services.fanout; a frame too large for one notification goes by its rows' ids alone,
and is read back); the owner feeds them to its tracker without reading the database, and sends
every target change to the others, whose live targets show it. The processes try for free
locks every `OWNERSHIP_POLL_S`; one that gets a space (its owner died, and PostgreSQL freed the
lock with its connection) restores the space's tracks from what it last heard of them (or,
failing that, from the stored targets), keeping their ids (core Tracker.restore), then replays
the space's detections stored since. The trackers' process dying is recovered from the same
way."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

from sqlalchemy import or_, select

from core.errors import IntspaceError
from core.localization.tracking import LIVE_STATES, TrackSnapshot
from server.db.models import Camera, Detection
from server.services.targets import LIVE, LiveTarget
from server.services.tracking.ingest import CameraFrame, DetectionIn, camera_frames
from server.services.tracking.snapshots import live_of, snapshot_of
from server.services.tracking.trackers import SpaceTrackers
from server.services.tracking.wire import (
    DETECTIONS_CHANNEL,
    TARGETS_CHANNEL,
    frame_item,
    frame_of_item,
    id_runs,
)

log = logging.getLogger("server.services.tracking")

# How often a process tries for the free spaces' locks (s).
OWNERSHIP_POLL_S = 1.0
# A space taken over: stored detections replayed (s before now at most, and how many), when
# there are no tracks to restore the last _REPLAY_FRESH_S; stored targets older than
# _RESTORE_S are not restored (a labelled track waits 60 s for its label, the others 5 s).
_REPLAY_MAX_S = 10.0
_REPLAY_FRESH_S = 2.0
_REPLAY_LIMIT = 50_000
_RESTORE_S = 60.0
# Ids per query when reading notified detections.
_RUNS_PER_QUERY = 200


class SharedTrackers(SpaceTrackers):
    """The spaces' trackers, shared with the processes on the same database: camera frames
    queued here or sent to the process that tracks their space, spaces taken over."""

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
                    item = frame_item(f)
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
                self._fanout.publish(DETECTIONS_CHANNEL, {"space": space_id}, id_runs(ids) + marks)
        return late

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
            frames = [frame_of_item(i) for i in items if isinstance(i, dict)]
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
        # A box whose bottom is cut is stored but gives no floor position (ingest).
        rows = [r for r in rows if not (r.cut and "bottom" in r.cut)]
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
                appearance=None if r.appearance is None else tuple(r.appearance),
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
                seeds[v.track_id] = snapshot_of(v, self.config)
        stored_only: list[LiveTarget] = []
        with self._factory() as session:
            for row in self._live.stored_live(session, space_id):
                tid = int(row.track_id or 0)
                if tid in seeds or tid < 1 or row.t is None or row.xy is None or row.cov is None:
                    continue
                if now - float(row.last_seen or row.t) > _RESTORE_S:
                    continue
                v = live_of(row)
                stored_only.append(v)
                seeds[tid] = snapshot_of(v, self.config)
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
