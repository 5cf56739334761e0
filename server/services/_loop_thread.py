"""A service's background thread: one daemon thread running the service's loop, a stop flag the
loop watches, and a stop that sets it, wakes the loop and waits a bounded time for it to end."""

from __future__ import annotations

import threading
from collections.abc import Callable


class LoopThread:
    """The thread named `name` that runs `target` (the service's loop) until `stop`.

    The loop ends when it sees `stopping` (or returns from `wait`, which sleeps until the stop or
    `timeout`). `stop` sets the flag, sets `wake` (an event the loop sleeps on instead, when it
    has one) so that it need not sleep out its period, and joins the thread for at most
    `join_timeout` seconds: a loop stuck in a call is left to finish on its own (the thread is a
    daemon, so it never holds the process open)."""

    def __init__(
        self,
        target: Callable[[], None],
        name: str,
        *,
        join_timeout: float,
        wake: threading.Event | None = None,
    ) -> None:
        self.name = name
        self.join_timeout = join_timeout
        self._target = target
        self._wake = wake
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def stopping(self) -> bool:
        """Whether the loop was asked to stop."""
        return self._stop.is_set()

    def wait(self, timeout: float) -> bool:
        """Sleep until the stop or for `timeout` s; return whether the loop was asked to stop."""
        return self._stop.wait(timeout)

    @property
    def started(self) -> bool:
        """Whether the thread was started and not stopped since."""
        return self._thread is not None

    @property
    def alive(self) -> bool:
        """Whether the thread was started, not stopped since, and still runs."""
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> None:
        """Clear the stop flag and start the thread."""
        self._stop.clear()
        self._thread = threading.Thread(target=self._target, name=self.name, daemon=True)
        self._thread.start()

    def stop(self) -> bool:
        """Ask the loop to stop, wake it, wait up to `join_timeout` s for the thread to end;
        return whether a thread had been started."""
        self._stop.set()
        if self._wake is not None:
            self._wake.set()
        thread, self._thread = self._thread, None
        if thread is None:
            return False
        thread.join(timeout=self.join_timeout)
        return True
