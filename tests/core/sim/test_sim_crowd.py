"""The twin's people give way to each other: core.sim.crowd."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInput
from core.sim.crowd import CONTACT_M, Crowd, script_positions
from core.sim.scene import Walker


def _crossing() -> list[Walker]:
    # Two people whose scripts reach the crossing at (0, 0) at the same instant (t = 2.5 s).
    return [
        Walker(name="east", waypoints=[(-2.0, 0.0), (2.0, 0.0)], speed=0.8),
        Walker(name="north", waypoints=[(0.0, -2.0), (0.0, 2.0)], speed=0.8),
    ]


def test_one_walker_follows_its_script_exactly():
    w = Walker(
        name="w", waypoints=[(0.0, 0.0), (3.0, 0.0), (3.0, 2.0)], speed=0.7, pauses=[1, 0, 2]
    )
    t = np.linspace(-3.0, 60.0, 777)
    np.testing.assert_array_equal(Crowd([w]).positions(t)[:, 0], script_positions(w, t))


def test_the_second_walker_waits_at_a_crossing_and_catches_up_later():
    people = _crossing()
    t = np.arange(0.0, 20.0, 0.05)
    alone = np.stack([script_positions(w, t) for w in people], axis=1)
    assert np.linalg.norm(alone[:, 0] - alone[:, 1], axis=1).min() < 0.05  # would collide
    walk = Crowd(people)
    xy = walk.positions(t)
    # Right of way: its script (to rounding: the crowd counts time in grid steps).
    np.testing.assert_allclose(xy[:, 0], alone[:, 0], rtol=0, atol=1e-12)
    gap = np.linalg.norm(xy[:, 0] - xy[:, 1], axis=1)
    # The one who yields keeps the comfort distance while the other crosses its way.
    assert gap.min() > 0.4 + CONTACT_M
    # It stays on its own line and walks on after waiting: it reaches the far end later.
    assert np.abs(xy[:, 1, 0]).max() == 0.0
    arrive_alone = t[np.argmax(alone[:, 1, 1] > 1.99)]
    arrive = t[np.argmax(xy[:, 1, 1] > 1.99)]
    assert 0.5 < arrive - arrive_alone < 5.0, (arrive_alone, arrive)
    assert walk.overlap_s == 0.0


def test_head_on_scripts_do_not_freeze_the_home():
    # Two people meeting head-on in a corridor cannot get round each other on their lines:
    # after max_wait_s they walk on and the overlap is counted for the scenario to report.
    people = [
        Walker(name="a", waypoints=[(0.0, 0.0), (6.0, 0.0)], speed=1.0),
        Walker(name="b", waypoints=[(6.0, 0.0), (0.0, 0.0)], speed=1.0),
    ]
    walk = Crowd(people, max_wait_s=3.0)
    xy = walk.positions(np.arange(0.0, 30.0, 0.1))
    assert walk.overlap_s > 0.0
    assert xy[:, 0, 0].max() > 5.9 and xy[:, 1, 0].min() < 0.1  # both got to their ends


def test_answers_do_not_depend_on_how_time_is_asked():
    people = [*_crossing(), Walker(name="c", waypoints=[(1.0, -1.5), (1.0, 1.5)], speed=0.6)]
    t = np.arange(0.0, 120.0, 0.1)
    whole = Crowd(people).positions(t)
    short_memory = Crowd(people, keep_s=5.0)
    pieces = np.concatenate([short_memory.positions(t[i : i + 37]) for i in range(0, len(t), 37)])
    np.testing.assert_array_equal(pieces, whole)
    # A time older than the memory walks again from 0 and gives the same place.
    np.testing.assert_array_equal(short_memory.positions(t[:50]), whole[:50])


def test_bad_times_and_settings_are_refused():
    with pytest.raises(InvalidInput):
        Crowd(_crossing()).positions([0.0, float("nan")])
    with pytest.raises(InvalidInput):
        Crowd(_crossing(), dt=0.0)


def test_a_vehicle_keeps_its_path_and_walkers_wait_for_it():
    # A robot driving across a walker's line at the moment the walker would be there: the
    # robot has right of way and keeps its planned motion exactly; the walker waits for it.
    t_path = np.arange(0.0, 10.0, 0.05)
    robot_xy = np.column_stack(
        [-2.0 + 0.8 * t_path, np.zeros_like(t_path)]
    )  # crosses (0, 0) at 2.5 s
    north = Walker(name="north", waypoints=[(0.0, -2.0), (0.0, 2.0)], speed=0.8)
    walk = Crowd([north], vehicles=[(t_path, robot_xy, 0.25)])
    t = np.arange(0.0, 9.0, 0.05)
    xy = walk.positions(t)
    np.testing.assert_allclose(walk.script_times(t)[:, 0], t, rtol=0, atol=1e-9)
    np.testing.assert_allclose(xy[:, 0, 0], -2.0 + 0.8 * t, rtol=0, atol=1e-9)
    gap = np.linalg.norm(xy[:, 0] - xy[:, 1], axis=1)
    assert gap.min() > 0.45 + CONTACT_M
    assert walk.overlap_s == 0.0
    alone = script_positions(north, t)
    assert np.linalg.norm(alone - robot_xy[: len(t)], axis=1).min() < 0.05  # would collide
