"""Zones: point in polygon against shapely (GEOS, an independent implementation), and the
inertia state machine against hand-worked timelines."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from core.errors import InvalidInput
from core.geometry.polygon import points_in_polygons
from core.localization.zones import Zone, ZoneOccupancy

SQUARE = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [0.0, 3.0]])
L_SHAPE = np.array([[4.0, 0.0], [8.0, 0.0], [8.0, 5.0], [6.0, 5.0], [6.0, 2.0], [4.0, 2.0]])


def test_points_in_polygons_matches_shapely() -> None:
    rng = np.random.default_rng(3)
    # A star polygon (concave, 14 vertices) and the two floor shapes.
    ang = np.linspace(0, 2 * np.pi, 14, endpoint=False)
    radius = np.where(np.arange(14) % 2 == 0, 3.0, 1.2)
    star = np.c_[10 + radius * np.cos(ang), 2 + radius * np.sin(ang)]
    polys = [SQUARE, L_SHAPE, star]
    pts = rng.uniform([-1, -2], [14, 7], size=(5000, 2))
    got = points_in_polygons(pts, polys)
    want = np.stack(
        [shapely.contains_xy(shapely.Polygon(p), pts[:, 0], pts[:, 1]) for p in polys], axis=1
    )
    # Points exactly on an edge have probability zero with uniform draws: equality is exact.
    assert got.shape == (5000, 3)
    assert np.array_equal(got, want)
    assert got.sum() > 500  # the test exercises the inside branch


def walk(occ: ZoneOccupancy, target: int, samples, kind: str = "person"):
    events = []
    for t, xy in samples:
        events += occ.update(target, kind, xy, t)
    return events


def test_enter_after_inertia_and_leave_after_inertia() -> None:
    occ = ZoneOccupancy([Zone("a", SQUARE, inertia_s=1.0), Zone("b", L_SHAPE, inertia_s=1.0)])
    # Outside both, then into a at t=1.0, stays to t=2.4, goes to b at t=2.5.
    samples = [(0.0, (-1, 1))] + [(1.0 + 0.1 * k, (2, 1)) for k in range(15)]
    samples += [(2.5 + 0.1 * k, (7, 1)) for k in range(16)]
    events = walk(occ, 7, samples)
    kinds = [(e.type, e.zone, round(e.t, 3)) for e in events]
    # Enter a decided by the first sample >= 1.0 s after the first inside one (t=1.0 -> 2.0);
    # leave a and enter b both 1.0 s after t=2.5.
    assert kinds == [
        ("new", None, 0.0),
        ("enter", "a", 2.0),
        ("leave", "a", 3.5),
        ("enter", "b", 3.5),
    ]
    assert occ.occupancy() == {"a": 0, "b": 1}
    ends = occ.end(7, (7, 1), 5.0)
    assert [(e.type, e.zone) for e in ends] == [("leave", "b"), ("end", None)]
    assert occ.occupancy() == {"a": 0, "b": 0} and len(occ) == 0


def test_short_visit_does_not_enter_and_flicker_does_not_leave() -> None:
    occ = ZoneOccupancy([Zone("a", SQUARE, inertia_s=1.0)])
    # 0.5 s inside, then out: no enter.
    events = walk(occ, 1, [(0.1 * k, (1, 1)) for k in range(6)] + [(0.6, (5, 5))])
    assert [e.type for e in events] == ["new"]
    # Enter, then 0.4 s outside and back: still in, no leave.
    events = walk(occ, 1, [(1.0 + 0.1 * k, (1, 1)) for k in range(12)])
    events += walk(occ, 1, [(2.2 + 0.1 * k, (5, 5)) for k in range(4)])
    events += walk(occ, 1, [(2.6 + 0.1 * k, (1, 1)) for k in range(20)])
    assert [e.type for e in events] == ["enter"]
    assert occ.occupancy()["a"] == 1


def test_loiter_once_and_robots_do_not_occupy() -> None:
    occ = ZoneOccupancy([Zone("a", SQUARE, inertia_s=0.0, loiter_s=3.0)])
    events = walk(occ, 1, [(0.5 * k, (1, 1)) for k in range(10)])
    assert [(e.type, e.t) for e in events] == [("new", 0.0), ("enter", 0.0), ("loiter", 3.0)]
    robot = walk(occ, 2, [(0.5 * k, (1, 1)) for k in range(10)], kind="robot")
    assert [e.type for e in robot] == ["new"]
    assert occ.occupancy() == {"a": 1}


def test_two_people_count_two_and_changed_zone_starts_empty() -> None:
    occ = ZoneOccupancy([Zone("a", SQUARE, inertia_s=0.5)])
    for tid in (1, 2):
        walk(occ, tid, [(0.25 * k, (1 + tid * 0.5, 1)) for k in range(4)])
    assert occ.occupancy() == {"a": 2} and occ.members("a") == [1, 2]
    assert occ.set_zones([Zone("a", SQUARE * 1.01, inertia_s=0.5)]) == ["a"]
    assert occ.occupancy() == {"a": 0}
    assert occ.set_zones([Zone("a", SQUARE * 1.01, inertia_s=0.5)]) == []
    assert occ.forget_except([2]) == [1] and len(occ) == 1


def test_bad_zone_and_bad_position_are_refused() -> None:
    with pytest.raises(InvalidInput, match="N >= 3"):
        Zone("x", [[0, 0], [1, 1]])
    with pytest.raises(InvalidInput, match="inertia_s"):
        Zone("x", SQUARE, inertia_s=-1)
    with pytest.raises(InvalidInput, match="finite"):
        ZoneOccupancy([Zone("a", SQUARE)]).update(1, "person", (np.nan, 0), 0.0)
