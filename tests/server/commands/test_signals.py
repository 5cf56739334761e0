"""A command stops on SIGTERM even when the signal lands while its main thread holds the stop
event's own lock (inside `stop.wait()`): the interleaving that left an `intspace worker`
running for ever after SIGTERM."""

from __future__ import annotations

import os
import signal
import threading

from server.commands._signals import stop_on_signals


def test_a_signal_inside_the_events_lock_still_stops():
    saved = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    stop = threading.Event()
    announced: list[int] = []
    try:
        stop_on_signals(stop, announced.append)
        # Hold the lock Event.wait holds between its checks, and take the signal there: a
        # handler that set the event itself would wait for this lock in this very thread.
        with stop._cond:  # the interleaving, made certain
            os.kill(os.getpid(), signal.SIGTERM)
        assert stop.wait(5.0)
        assert announced == [signal.SIGTERM]
    finally:
        for s, handler in saved.items():
            signal.signal(s, handler)
