"""Zones on the floor plan: which targets are in which zone, with inertia, and the events.

A zone is a simple polygon on the floor (world frame, metres) with an inertia (s) and a
loitering time (s). A target is inside a zone when its floor position is (`points_in_polygons`,
the even-odd ray crossing test of Shimrat, "Algorithm 112: Position of point relative to
polygon", CACM 1962, vectorised over every edge of every zone). `ZoneOccupancy` follows each
target's membership through a small state machine per (target, zone), fed with the target's
positions at the capture times of the detections that moved it:

* out -> in: the target is inside at time t0; once a later position, still inside, is at least
  `inertia_s` after t0, it has entered (an `enter` event at that position's time). A target
  born inside enters the same way, after the inertia.
* in -> out: the same with outside positions; or at once when the target ends.
* `loiter`: once, when a target that entered has been inside for `loiter_s` (> 0) since it
  first was (the start of its run inside).

Only people count: occupancy of a zone is the number of `person` targets that have entered it
and not left. One person seen by several cameras is one target of the tracker, so nothing here
can count them twice. Every live target (any kind) gives a `new` event when first reported and
an `end` event when it ends. No I/O and no clock: time is what the caller passes.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Iterable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import InvalidInput
from core.geometry.polygon import points_in_polygons

Array = NDArray[np.float64]

EVENT_TYPES = ("enter", "leave", "loiter", "new", "end")
# The kind of target that occupies zones.
OCCUPANT_KIND = "person"


@dataclass(frozen=True)
class Zone:
    """A zone: `key` (any hashable id), `polygon` (N, 2) metres, N >= 3, `inertia_s` >= 0,
    `loiter_s` >= 0 (0: no loiter event)."""

    key: Hashable
    polygon: Array
    inertia_s: float = 1.0
    loiter_s: float = 0.0

    def __post_init__(self) -> None:
        poly = np.asarray(self.polygon, dtype=np.float64)
        if poly.ndim != 2 or poly.shape[1] != 2 or poly.shape[0] < 3:
            raise InvalidInput(f"zone {self.key!r}: polygon must have shape (N >= 3, 2)")
        if not np.all(np.isfinite(poly)):
            raise InvalidInput(f"zone {self.key!r}: polygon has NaN or infinite vertices")
        for name in ("inertia_s", "loiter_s"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise InvalidInput(f"zone {self.key!r}: {name} must be >= 0 s, got {value!r}")
        object.__setattr__(self, "polygon", poly)


@dataclass(frozen=True)
class ZoneEvent:
    """An event: `type` (one of EVENT_TYPES), target id, its kind, the zone's key (None for
    `new` and `end`), the target's position (2,) metres and the time t (s) of the position
    that decided it."""

    type: str
    target: int
    kind: str
    zone: Hashable | None
    xy: tuple[float, float]
    t: float


@dataclass
class _Membership:
    """One target's state in one zone: counted in or not; since when its position has been on
    the other side (None: on the counted side); since when it has been inside (the run)."""

    counted: bool = False
    other_since: float | None = None
    inside_since: float | None = None
    loitered: bool = False


@dataclass
class _TargetState:
    kind: str
    zones: dict[Hashable, _Membership] = field(default_factory=dict)


class ZoneOccupancy:
    """Occupancy of a space's zones and their events, from its targets' updates (module
    docstring). Not thread-safe: one caller (the tracker's side) at a time."""

    def __init__(self, zones: Iterable[Zone] = ()) -> None:
        self._zones: dict[Hashable, Zone] = {}
        self._targets: dict[int, _TargetState] = {}
        self.set_zones(zones)

    @property
    def zones(self) -> tuple[Zone, ...]:
        """The zones followed."""
        return tuple(self._zones.values())

    def __len__(self) -> int:
        """The number of targets followed (live targets reported and not ended)."""
        return len(self._targets)

    def set_zones(self, zones: Iterable[Zone]) -> list[Hashable]:
        """Follow these zones from now on; return the keys of zones whose shape or timing
        changed or that are new. A changed or new zone starts empty (its members enter again
        after its inertia); a zone no longer given is forgotten (no events)."""
        new = {z.key: z for z in zones}
        changed = []
        for key, zone in new.items():
            old = self._zones.get(key)
            same = (
                old is not None
                and old.polygon.shape == zone.polygon.shape
                and np.array_equal(old.polygon, zone.polygon)
                and old.inertia_s == zone.inertia_s
                and old.loiter_s == zone.loiter_s
            )
            if not same:
                changed.append(key)
        for state in self._targets.values():
            for key in list(state.zones):
                if key not in new or key in changed:
                    del state.zones[key]
        self._zones = new
        return changed

    def occupancy(self) -> dict[Hashable, int]:
        """Return the number of people counted in each zone."""
        counts = dict.fromkeys(self._zones, 0)
        for state in self._targets.values():
            if state.kind != OCCUPANT_KIND:
                continue
            for key, m in state.zones.items():
                if m.counted:
                    counts[key] += 1
        return counts

    def members(self, key: Hashable) -> list[int]:
        """Return the ids of the people counted in zone `key`."""
        return sorted(
            tid
            for tid, s in self._targets.items()
            if s.kind == OCCUPANT_KIND and key in s.zones and s.zones[key].counted
        )

    def update(self, target: int, kind: str, xy: ArrayLike, t: float) -> list[ZoneEvent]:
        """Take a live target's position (2,) metres at time t (s, the capture time of the
        detection that gave it); return the events it decides, in order."""
        p = np.asarray(xy, dtype=np.float64).reshape(2)
        if not np.all(np.isfinite(p)) or not math.isfinite(t):
            raise InvalidInput(f"target {target}: position and time must be finite")
        where = (float(p[0]), float(p[1]))
        events: list[ZoneEvent] = []
        state = self._targets.get(target)
        if state is None:
            state = self._targets[target] = _TargetState(kind)
            events.append(ZoneEvent("new", target, kind, None, where, t))
        state.kind = kind
        if kind != OCCUPANT_KIND or not self._zones:
            return events
        keys = list(self._zones)
        inside = points_in_polygons(p[None], [self._zones[k].polygon for k in keys])[0]
        for key, now_in in zip(keys, inside.tolist(), strict=True):
            zone = self._zones[key]
            m = state.zones.get(key)
            if m is None:
                if not now_in:
                    continue  # nothing to remember about a zone it has never been in
                m = state.zones[key] = _Membership()
            if now_in and m.inside_since is None:
                m.inside_since = t
            elif not now_in:
                m.inside_since = None
                m.loitered = False
            if now_in != m.counted:
                if m.other_since is None:
                    m.other_since = t
                if t - m.other_since >= zone.inertia_s:
                    m.counted, m.other_since = now_in, None
                    events.append(
                        ZoneEvent("enter" if now_in else "leave", target, kind, key, where, t)
                    )
            else:
                m.other_since = None
            if (
                m.counted
                and zone.loiter_s > 0
                and not m.loitered
                and m.inside_since is not None
                and t - m.inside_since >= zone.loiter_s
            ):
                m.loitered = True
                events.append(ZoneEvent("loiter", target, kind, key, where, t))
            if not m.counted and m.other_since is None and m.inside_since is None:
                del state.zones[key]  # outside and counted out: nothing left to follow
        return events

    def end(self, target: int, xy: ArrayLike, t: float) -> list[ZoneEvent]:
        """The target ended at time t at xy (2,): return its `leave` events (the zones it was
        counted in) and its `end` event; it is forgotten. An unknown target gives none."""
        state = self._targets.pop(target, None)
        if state is None:
            return []
        p = np.asarray(xy, dtype=np.float64).reshape(2)
        where = (float(p[0]), float(p[1]))
        events = [
            ZoneEvent("leave", target, state.kind, key, where, t)
            for key, m in state.zones.items()
            if m.counted
        ]
        events.append(ZoneEvent("end", target, state.kind, None, where, t))
        return events

    def targets(self) -> list[int]:
        """Return the ids of the targets followed."""
        return list(self._targets)

    def forget_except(self, live: Iterable[int]) -> list[int]:
        """Forget the targets not in `live` without events (their end was missed: a reset
        tracker); return their ids."""
        keep = set(live)
        gone = [tid for tid in self._targets if tid not in keep]
        for tid in gone:
            del self._targets[tid]
        return gone
