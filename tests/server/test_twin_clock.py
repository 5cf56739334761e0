"""The twin's clock: the simulated home keeps the service's time when its steps come late."""

from __future__ import annotations

import threading
import time

import pytest

from core.sim import default_scene
from server.services.twin import MAX_CATCH_UP_S, Twin


def _run(twin: Twin, seconds: float) -> None:
    twin.start()
    time.sleep(seconds)
    twin.stop()


def _twin(step_s: float, periods: list[float]) -> Twin:
    """A twin at 5 Hz whose steps only record what they are asked to advance and take
    `step_s` seconds (rendering and detecting on a loaded machine)."""
    twin = Twin(default_scene(), None, None, None, rate_hz=5.0)  # type: ignore[arg-type]
    twin._learn_background = lambda camera: None  # type: ignore[method-assign,assignment,return-value]

    def step(period: float) -> None:
        periods.append(period)
        time.sleep(step_s)

    twin.step = step  # type: ignore[method-assign]
    return twin


def test_late_steps_advance_the_world_by_the_whole_periods_that_passed() -> None:
    # Steps of 0.5 s at 5 Hz: the world advances by 0.4 or 0.6 s (whole periods, the instants
    # stay on the 0.2 s grid), 0.5 s a step on average, not by the 0.2 s period (which slowed
    # it to 0.4x real time while the frames kept real time).
    periods: list[float] = []
    _run(_twin(0.5, periods), 3.2)
    assert len(periods) >= 5
    assert periods[0] == pytest.approx(0.2)
    late = periods[1:]
    assert all(round(p / 0.2, 9) in (2, 3) for p in late), late
    assert abs(sum(late) - 0.5 * len(late)) <= 0.2


def test_a_step_in_time_advances_one_period_and_a_stall_at_most_the_catch_up() -> None:
    periods: list[float] = []
    _run(_twin(0.01, periods), 1.5)
    assert len(periods) >= 6 and all(p == pytest.approx(0.2) for p in periods), periods
    stalled: list[float] = []
    twin = _twin(0.0, stalled)
    release = threading.Event()

    def stall(period: float) -> None:
        stalled.append(period)
        if len(stalled) == 2:
            release.wait(3.0)  # the machine stops for 3 s

    twin.step = stall  # type: ignore[method-assign]
    _run(twin, 4.0)
    assert len(stalled) >= 3
    assert stalled[2] == pytest.approx(MAX_CATCH_UP_S)
