"""The twin's clock: the simulated home keeps the service's time when its steps come late.

The checks hold whatever the machine's load: they compare the world's advance with the time
that really passed between the steps, measured by the steps themselves."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from core.sim import default_scene
from server.services.twin import MAX_CATCH_UP_S, Twin
from tests.support.waiting import wait_until

PERIOD = 0.2  # 5 Hz


def _run(twin: Twin, calls: list, steps: int) -> None:
    """Run `twin` until it has taken `steps` steps (recorded in `calls`)."""
    twin.start()
    try:
        wait_until(
            lambda: len(calls) >= steps,
            what=f"{steps} steps of the twin",
            stalled_after_s=10,
            progress=lambda: len(calls),
            poll_s=0.02,
        )
    finally:
        twin.stop()


def _twin(step_s: float, calls: list[tuple[float, float]]) -> Twin:
    """A twin at 5 Hz whose steps record (when, what they are asked to advance) and take
    `step_s` seconds (rendering and detecting on a loaded machine)."""
    twin = Twin(default_scene(), None, None, None, rate_hz=1 / PERIOD)  # type: ignore[arg-type]
    twin._learn_background = lambda camera: None  # type: ignore[method-assign,assignment,return-value]

    def step(period: float) -> None:
        calls.append((time.monotonic(), period))
        time.sleep(step_s)  # a step's own duration: the lateness is the scenario

    twin.step = step  # type: ignore[method-assign]
    return twin


def _whole_periods(periods: np.ndarray) -> np.ndarray:
    k = periods / PERIOD
    assert np.allclose(k, np.round(k), atol=1e-9), periods
    return np.round(k).astype(int)


def test_late_steps_advance_the_world_by_the_time_that_passed() -> None:
    # Steps of 0.5 s at 5 Hz. Advancing one period each (as before) ran the world at 0.4x
    # the time its frames were stamped with; now it advances by the whole periods that have
    # passed: 2 or 3 (the instants stay on the 0.2 s grid), in all the time between the steps.
    calls: list[tuple[float, float]] = []
    _run(_twin(0.5, calls), calls, 6)
    assert len(calls) >= 5
    when, periods = np.array(calls).T
    assert periods[0] == pytest.approx(PERIOD)
    assert np.all(_whole_periods(periods[1:]) >= 2)
    # In all, the world advanced by the time from the first step to the last (the first step
    # advances a period ahead; the last may leave less than a period owed).
    assert abs(periods.sum() - (when[-1] - when[0])) <= PERIOD


def test_steps_in_time_advance_one_period_and_a_stall_at_most_the_catch_up() -> None:
    calls: list[tuple[float, float]] = []
    _run(_twin(0.01, calls), calls, 8)
    when, periods = np.array(calls).T
    assert len(periods) >= 5
    assert np.median(_whole_periods(periods)) == 1
    assert abs(periods.sum() - (when[-1] - when[0])) <= PERIOD
    # A machine that stops for 3 s: the next step advances MAX_CATCH_UP_S, not 3 s.
    stalled: list[float] = []
    twin = _twin(0.0, [])
    release = threading.Event()

    def stall(period: float) -> None:
        stalled.append(period)
        if len(stalled) == 2:
            release.wait(3.0)

    twin.step = stall  # type: ignore[method-assign]
    _run(twin, stalled, 3)
    assert len(stalled) >= 3
    assert stalled[2] == pytest.approx(MAX_CATCH_UP_S)
