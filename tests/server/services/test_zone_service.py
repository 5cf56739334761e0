"""The zones service without a broker: a target whose end the tracker never reported (its
process died and it was restarted) is forgotten after two checks, never at the first."""

from __future__ import annotations

import numpy as np

from core.localization.tracking import TrackSnapshot, TrackState
from server.db.models import Room, Space
from server.services.zones import ZoneService
from tests.support.sqlite_copy import copied_database


def _snap(track_id: int, x: float, t: float) -> TrackSnapshot:
    return TrackSnapshot(
        id=track_id,
        kind="person",
        label=None,
        state=TrackState.CONFIRMED,
        t=t,
        x=np.array([x, 1.0, 0.0, 0.0]),
        cov=np.eye(4) * 0.01,
        hits=5,
        first_seen=0.0,
        last_seen=t,
    )


def test_targets_whose_end_never_came_are_forgotten(tmp_path, sqlite_template):
    factory = copied_database(sqlite_template, tmp_path)
    with factory() as session:
        space = Space(name="Flat")
        session.add(space)
        session.flush()
        session.add(
            Room(space_id=space.id, name="Living", polygon=[[0, 0], [4, 0], [4, 3], [0, 3]])
        )
        session.commit()
        sid = space.id
    live = {1, 2}
    zones = ZoneService(factory, tracked=lambda _: set(live))
    published: list[int] = []

    class Sink:
        def zones_defined(self, *args): ...
        def event(self, *args): ...
        def target(self, *args): ...
        def forget_space(self, *args): ...
        def occupancy(self, space_id, zone, count):
            published.append(count)

    zones.sinks.append(Sink())
    zones.reload()
    for k in range(20):  # two people inside for 2 s: counted after the room's 1 s inertia
        zones.on_targets(sid, (_snap(1, 1.0, 0.1 * k), _snap(2, 2.0, 0.1 * k)))
    assert list(zones.occupancy(sid).values()) == [2] and zones.followed() == 2
    live.discard(2)  # the tracker lost track 2 without reporting its end
    zones._prune()
    assert zones.followed() == 2  # one check is not enough: it may just be starting
    zones._prune()
    assert zones.followed() == 1 and list(zones.occupancy(sid).values()) == [1]
    assert published == [0, 2, 1]  # defined, both entered at the same update, one forgotten
