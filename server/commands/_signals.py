"""Stopping a long-running command on SIGTERM or SIGINT without deadlocking it."""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable


def stop_on_signals(stop: threading.Event, announce: Callable[[int], None] | None = None) -> None:
    """Set `stop` when the process receives SIGTERM or SIGINT; `announce(signum)` first, when
    given (a log line).

    A Python signal handler runs in the main thread between two bytecodes, which may be inside
    `stop.wait()` holding the event's own lock, or inside a logging call holding the handler's
    lock. Setting the event or logging there can then wait for a lock the interrupted thread
    holds, for ever. So the handler only starts a short thread that does both.
    """

    def act(signum: int) -> None:
        if announce is not None:
            announce(signum)
        stop.set()

    def on_signal(signum: int, _frame: object) -> None:
        threading.Thread(target=act, args=(signum,), name="stop-signal", daemon=True).start()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
