"""The services' background thread (server.services._loop_thread.LoopThread): a stop ends a loop
that sleeps on the stop flag or on its wake event at once, not after its period, and a loop that
will not end does not hold the stop longer than its join timeout."""

from __future__ import annotations

import threading
import time

from server.services._loop_thread import LoopThread

# A loop period far longer than any stop may take: a stop that had to sleep it out fails.
_PERIOD_S = 60.0
# What a stop may take on a loaded machine (joining a thread that was woken): a few seconds.
_PROMPT_S = 5.0


def test_a_stop_wakes_a_loop_sleeping_on_the_stop_flag() -> None:
    rounds: list[float] = []
    seen: dict[str, object] = {}

    def loop() -> None:
        seen["thread"] = threading.current_thread()
        while not runner.wait(_PERIOD_S):
            rounds.append(time.monotonic())

    runner = LoopThread(loop, "test-loop", join_timeout=_PERIOD_S)
    assert not runner.started and not runner.stop()  # never started: nothing to stop
    runner.start()
    assert runner.started
    deadline = time.monotonic() + _PROMPT_S
    while "thread" not in seen:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    thread = seen["thread"]
    assert isinstance(thread, threading.Thread)
    assert thread.name == "test-loop" and thread.daemon and runner.alive
    t0 = time.monotonic()
    assert runner.stop()
    assert time.monotonic() - t0 < _PROMPT_S
    assert not thread.is_alive() and not runner.started and not runner.alive
    assert runner.stopping and rounds == []


def test_a_stop_sets_the_wake_event_and_a_start_runs_again() -> None:
    wake = threading.Event()
    rounds: list[int] = []

    def loop() -> None:
        while not runner.stopping:
            wake.wait(_PERIOD_S)
            wake.clear()
            rounds.append(1)

    runner = LoopThread(loop, "test-wake", join_timeout=_PERIOD_S, wake=wake)
    for n in (1, 2):
        runner.start()
        assert not runner.stopping  # a start clears the last stop
        time.sleep(0.05)
        t0 = time.monotonic()
        assert runner.stop()
        assert time.monotonic() - t0 < _PROMPT_S
        assert len(rounds) == n  # woken once by each stop, then it saw the flag


def test_a_loop_that_will_not_end_holds_the_stop_no_longer_than_the_join_timeout() -> None:
    release = threading.Event()
    runner = LoopThread(lambda: release.wait(_PERIOD_S), "test-stuck", join_timeout=0.2)
    runner.start()
    try:
        t0 = time.monotonic()
        assert runner.stop()
        took = time.monotonic() - t0
        assert 0.2 <= took < _PROMPT_S
        assert not runner.started
    finally:
        release.set()
