"""The spaces' zones (spec 09): their definitions read from the database (the zones table and
the rooms, which are zones too), and their occupancy and events from the tracker's targets.

`ZoneService.on_targets` is called by the tracking service's thread with every frame's
confirmed and coasting target updates and with the targets that ended (server.services.
tracking), for the spaces whose tracker runs in this process; it feeds core's ZoneOccupancy
(core.localization.zones) and hands the events and occupancy changes to the home publisher
(MQTT, when configured). It does no I/O on that thread: the definitions are reloaded from the
database by its own thread (at once when this process's API changed them, else every
`_RELOAD_S`, so changes made through another process's API are picked up too).
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections.abc import Callable, Hashable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from core.errors import IntspaceError
from core.localization.tracking import TrackSnapshot
from core.localization.zones import Zone as CoreZone
from core.localization.zones import ZoneEvent, ZoneOccupancy, points_in_polygons
from server.db.models import Room, Space
from server.db.models import Zone as ZoneRow
from server.schemas.zones import ZoneRead
from server.services._loop_thread import LoopThread

log = logging.getLogger(__name__)

# Reload the zones' definitions at least this often (s): changes made by another process.
_RELOAD_S = 1.0
_PRUNE_S = 10.0
# A room is a zone with this inertia (s) and no loitering (spec 09).
ROOM_INERTIA_S = 1.0
_SLUG_RUN = re.compile(r"[^a-z0-9]+")


def slugify(name: str) -> str:
    """Return the slug of a name: lower case, each run of other characters one "-" ("Living
    room" -> "living-room"); "" when the name has no letter or digit."""
    return _SLUG_RUN.sub("-", name.lower()).strip("-")


@dataclass(frozen=True)
class ZoneDef:
    """A zone as the service follows it: `key` ("zone", id) or ("room", id), its space, name,
    slug, polygon (metres), inertia and loitering (s); rooms are read-only."""

    key: tuple[str, int]
    space_id: int
    name: str
    slug: str
    polygon: tuple[tuple[float, float], ...]
    inertia_s: float
    loiter_s: float

    @property
    def read_only(self) -> bool:
        """Whether it is a room (changed through the rooms API only)."""
        return self.key[0] == "room"

    @property
    def object_id(self) -> str:
        """The zone's id in Home Assistant unique ids: "<id>" for a zone, "room<id>" for a
        room (their ids are counted apart)."""
        kind, i = self.key
        return str(i) if kind == "zone" else f"room{i}"

    def core(self) -> CoreZone:
        """Return the core zone."""
        return CoreZone(self.key, list(self.polygon), self.inertia_s, self.loiter_s)  # type: ignore[arg-type]


class HomeSink(Protocol):
    """Where zone changes go (the MQTT publisher): called on the tracker's thread, must not
    block."""

    def zones_defined(self, space_id: int, space_name: str, zones: Sequence[ZoneDef]) -> None:
        """The definitions of a space's zones (all of them), after any change."""

    def occupancy(self, space_id: int, zone: ZoneDef, count: int) -> None:
        """A zone's occupancy changed (or was just defined)."""

    def event(self, space_id: int, zone: ZoneDef | None, event: ZoneEvent) -> None:
        """An event of a space."""

    def target(self, space_id: int, snap: TrackSnapshot) -> None:
        """A live target's new state."""

    def forget_space(self, space_id: int) -> None:
        """This process no longer runs the space's tracker: stop publishing it."""


def load_zone_defs(session: Session, space_id: int | None = None) -> list[ZoneDef]:
    """Return the zones and rooms (of one space, or all) as ZoneDefs; a room whose name has no
    slug is named "room-<id>"."""
    zones = select(ZoneRow).order_by(ZoneRow.id)
    rooms = select(Room).order_by(Room.id)
    if space_id is not None:
        zones = zones.where(ZoneRow.space_id == space_id)
        rooms = rooms.where(Room.space_id == space_id)
    defs = [
        ZoneDef(
            ("room", r.id),
            r.space_id,
            r.name,
            slugify(r.name) or f"room-{r.id}",
            tuple((float(x), float(y)) for x, y in r.polygon),
            ROOM_INERTIA_S,
            0.0,
        )
        for r in session.scalars(rooms)
    ]
    defs += [
        ZoneDef(
            ("zone", z.id),
            z.space_id,
            z.name,
            z.slug,
            tuple((float(x), float(y)) for x, y in z.polygon),
            float(z.inertia_s),
            float(z.loiter_s),
        )
        for z in session.scalars(zones)
    ]
    return defs


class _SpaceZones:
    def __init__(self) -> None:
        self.occupancy = ZoneOccupancy()
        self.defs: dict[Hashable, ZoneDef] = {}
        self.counts: dict[Hashable, int] = {}


class ZoneService:
    """Zones, occupancy and events of the spaces tracked in this process (module docstring).
    `owns(space_id)` says whether this process runs a space's tracker (the tracking service's
    `owns`); a space it stops owning is forgotten here and its publishing stops."""

    def __init__(
        self,
        factory: sessionmaker[Session],
        *,
        owns: Callable[[int | None], bool] = lambda _: True,
        live_xy: Callable[[int], list[tuple[str, list[float]]]] | None = None,
        tracked: Callable[[int], set[int]] | None = None,
    ) -> None:
        self._factory = factory
        self._owns = owns
        self._live_xy = live_xy
        # The ids of a space's live tracks (the tracker's), to forget targets whose end was
        # never reported (a tracker restarted after its process died): checked every
        # _PRUNE_S, a target absent from two checks in a row is forgotten.
        self._tracked = tracked
        self._absent: dict[int, set[int]] = {}
        self._last_prune = time.monotonic()
        self._lock = threading.Lock()
        self._spaces: dict[int, _SpaceZones] = {}
        self._defs: dict[int, list[ZoneDef]] = {}
        self._names: dict[int, str] = {}
        self.sinks: list[HomeSink] = []
        self._wake = threading.Event()
        self._runner = LoopThread(self._loop, "zones", join_timeout=5, wake=self._wake)
        self.errors = 0

    def attach_tracking(self, tracking: Any) -> None:
        """Use a TrackingService's `tracks` for the pruning (its live track ids per space)."""
        self._tracked = lambda space_id: {snap.id for snap in tracking.tracks(space_id)}

    # -- definitions --------------------------------------------------------------------------

    def reload(self) -> None:
        """Read every space's zones and rooms again; follow the changes."""
        with self._factory() as session:
            defs = load_zone_defs(session)
            names = {s.id: s.name for s in session.scalars(select(Space))}
        by_space: dict[int, list[ZoneDef]] = {sid: [] for sid in names}
        for d in defs:
            by_space.setdefault(d.space_id, []).append(d)
        owned = {sid for sid in by_space if self._owns(sid)}
        with self._lock:
            for space_id, zones in by_space.items():
                renamed = self._names.get(space_id) != names.get(space_id)
                fresh = space_id in owned and space_id not in self._spaces
                if fresh:
                    self._spaces[space_id] = _SpaceZones()
                if self._defs.get(space_id) == zones and not renamed and not fresh:
                    continue
                self._defs[space_id] = zones
                self._names[space_id] = names.get(space_id, f"space {space_id}")
                if space_id in self._spaces:
                    self._define(space_id)
            for space_id in set(self._defs) - set(by_space):
                del self._defs[space_id]  # the space was deleted
                self._spaces.pop(space_id, None)
                for sink in self.sinks:
                    sink.forget_space(space_id)

    def changed(self) -> None:
        """This process's API changed zones or rooms: reload at once (on the zones' thread)."""
        self._wake.set()

    def definitions(self, space_id: int) -> list[ZoneDef]:
        """Return the zones of a space as last loaded."""
        with self._lock:
            return list(self._defs.get(space_id, ()))

    def _define(self, space_id: int) -> None:
        """Give a space's core occupancy its zones, and the sinks the definitions. Call with
        the lock held."""
        space = self._spaces[space_id]
        zones = self._defs.get(space_id, [])
        space.defs = {d.key: d for d in zones}
        try:
            space.occupancy.set_zones([d.core() for d in zones])
        except IntspaceError as exc:  # the API validates; a row written by hand may not be
            log.warning("space %s: zones refused: %s", space_id, exc)
            return
        for sink in self.sinks:
            sink.zones_defined(space_id, self._names.get(space_id, ""), zones)
        counts = space.occupancy.occupancy()
        for key, n in counts.items():
            if space.counts.get(key) != n or key not in space.counts:
                for sink in self.sinks:
                    sink.occupancy(space_id, space.defs[key], n)
        space.counts = counts

    # -- from the tracker ---------------------------------------------------------------------

    def on_targets(
        self,
        space_id: int | None,
        updated: Iterable[TrackSnapshot],
        ended: Iterable[TrackSnapshot] = (),
    ) -> None:
        """Take a space's confirmed or coasting target updates and its ended targets (the
        tracker's thread): follow the zones, hand the events and changed counts on."""
        if space_id is None:
            return  # cameras without a space: no floor plan, no zones
        with self._lock:
            space = self._spaces.get(space_id)
            if space is None:
                space = self._spaces[space_id] = _SpaceZones()
                self._define(space_id)
            events: list[ZoneEvent] = []
            for snap in updated:
                events += space.occupancy.update(snap.id, snap.kind, snap.xy, snap.t)
                for sink in self.sinks:
                    sink.target(space_id, snap)
            for snap in ended:
                events += space.occupancy.end(snap.id, snap.xy, snap.t)
            if not events:
                return
            for e in events:
                zone = None if e.zone is None else space.defs.get(e.zone)
                for sink in self.sinks:
                    sink.event(space_id, zone, e)
            if any(e.zone is not None for e in events):
                self._publish_counts(space_id, space)

    def _publish_counts(self, space_id: int, space: _SpaceZones) -> None:
        """Hand the sinks the zones' counts that changed. Call with the lock held."""
        counts = space.occupancy.occupancy()
        for key, n in counts.items():
            if space.counts.get(key) != n:
                for sink in self.sinks:
                    sink.occupancy(space_id, space.defs[key], n)
        space.counts = counts

    def forget_ended(self, space_id: int | None, live: Iterable[int]) -> None:
        """Drop the targets of a space not in `live` (their end was not reported: a reset)."""
        with self._lock:
            space = self._spaces.get(space_id) if space_id is not None else None
            if space is not None:
                space.occupancy.forget_except(live)

    # -- reads --------------------------------------------------------------------------------

    def occupancy(self, space_id: int) -> dict[Hashable, int]:
        """Return the occupancy of a space's zones, by zone key. Where this process does not
        run the space's tracker, the live people inside each zone now (no inertia)."""
        with self._lock:
            space = self._spaces.get(space_id)
            if space is not None:
                return space.occupancy.occupancy()
            defs = list(self._defs.get(space_id, ()))
        if self._live_xy is None or not defs:
            return {d.key: 0 for d in defs}
        people = [xy for kind, xy in self._live_xy(space_id) if kind == "person"]
        if not people:
            return {d.key: 0 for d in defs}
        inside = points_in_polygons(people, [d.polygon for d in defs])
        return {d.key: int(n) for d, n in zip(defs, inside.sum(axis=0).tolist(), strict=True)}

    def followed(self) -> int:
        """Return the number of targets followed over every space (bounded by the live ones)."""
        with self._lock:
            return sum(len(s.occupancy) for s in self._spaces.values())

    # -- the thread ---------------------------------------------------------------------------

    def start(self) -> None:
        """Load the zones and start the thread that reloads them."""
        self.reload()
        self._runner.start()

    def stop(self) -> None:
        """Stop the thread."""
        self._runner.stop()

    def _loop(self) -> None:
        while not self._runner.stopping:
            self._wake.wait(_RELOAD_S)
            self._wake.clear()
            if self._runner.stopping:
                return
            try:
                self.reload()
                self._drop_lost()
                if time.monotonic() - self._last_prune >= _PRUNE_S:
                    self._last_prune = time.monotonic()
                    self._prune()
            except Exception:
                self.errors += 1
                log.exception("reloading the zones failed")
                time.sleep(_RELOAD_S)

    def _prune(self) -> None:
        if self._tracked is None:
            return
        with self._lock:
            spaces = {sid: set(space.occupancy.targets()) for sid, space in self._spaces.items()}
        for space_id, followed in spaces.items():
            gone = followed - self._tracked(space_id)
            stale = gone & self._absent.get(space_id, set())
            self._absent[space_id] = gone - stale
            if stale:
                with self._lock:
                    space = self._spaces.get(space_id)
                    if space is not None:
                        space.occupancy.forget_except(set(space.occupancy.targets()) - stale)
                        self._publish_counts(space_id, space)
                log.info(
                    "space %s: %d target(s) whose end was not reported forgotten",
                    space_id,
                    len(stale),
                )

    def _drop_lost(self) -> None:
        with self._lock:
            lost = [sid for sid in self._spaces if not self._owns(sid)]
            for space_id in lost:
                del self._spaces[space_id]
        for space_id in lost:
            for sink in self.sinks:
                sink.forget_space(space_id)


def zone_read(d: ZoneDef, occupancy: dict[Any, int] | None) -> ZoneRead:
    """Return a zone as the API shows it."""
    kind, i = d.key
    return ZoneRead(
        id=i if kind == "zone" else None,
        room_id=i if kind == "room" else None,
        space_id=d.space_id,
        name=d.name,
        slug=d.slug,
        polygon=[list(p) for p in d.polygon],
        inertia_s=d.inertia_s,
        loiter_s=d.loiter_s,
        read_only=d.read_only,
        occupancy=None if occupancy is None else occupancy.get(d.key, 0),
    )
