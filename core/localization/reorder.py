"""Frames of several cameras put back in time order within a latency window, for the tracker
(core.localization.tracking), which takes frames in time order only."""

from __future__ import annotations

import heapq
import itertools
import math
from dataclasses import dataclass, field

from core.errors import InvalidInput
from core.localization._checks import check_time


@dataclass(order=True)
class _Queued:
    t: float
    seq: int
    frame: object = field(compare=False)


class ReorderBuffer:
    """Puts frames from several cameras back in time order within a latency window.

    `push(t, frame)` queues a frame captured at time t; `pop_ready(now)` returns, oldest first,
    the frames captured at or before now - latency, and closes the window up to that time. A
    frame that arrives older than that (the tracker has moved past it) is refused by `push`
    (returns False) and counted in `late`. `limit` bounds the frames held; beyond it the
    oldest are released early.

    Frames pushed with their `source` (the camera) and `arrived` time (on the clock of `now`)
    also move a watermark: once every source heard from within the last `latency` seconds has
    delivered a frame captured at or after t, no frame older than t can still come from them
    (each camera's frames arrive in capture order), so frames up to t are released at once
    instead of at the window's end. The window stays the longest wait; a camera silent for
    longer than the window no longer holds the others back (its later frames older than the
    released time are late). Cameras that post every frame, even with nothing detected, keep
    the delay down to the slowest camera's own.
    """

    def __init__(self, latency: float = 0.15, limit: int = 10_000) -> None:
        if not math.isfinite(latency) or latency < 0:
            raise InvalidInput(f"latency must be >= 0 seconds, got {latency}")
        if not isinstance(limit, int) or limit < 1:
            raise InvalidInput(f"limit must be an integer >= 1, got {limit!r}")
        self.latency = float(latency)
        self.limit = limit
        self._heap: list[_Queued] = []
        self._seq = itertools.count()
        self._released: float = -math.inf
        # source -> (newest capture time, arrival time of that push)
        self._sources: dict[object, tuple[float, float]] = {}
        self.late = 0

    def __len__(self) -> int:
        return len(self._heap)

    @property
    def released(self) -> float:
        """The time up to which frames were released (-inf before any): older ones are late."""
        return self._released

    def push(
        self, t: float, frame: object, *, source: object = None, arrived: float | None = None
    ) -> bool:
        """Queue `frame` captured at time t (s) by `source`, which delivered it at `arrived`
        (both optional: the watermark, class docstring); return False (and count it) when it
        is late."""
        t = check_time(t)
        if source is not None and arrived is not None:
            arrived = check_time(arrived)
            newest = self._sources.get(source, (t, arrived))[0]
            self._sources[source] = (max(newest, t), arrived)
        if t < self._released:
            self.late += 1
            return False
        heapq.heappush(self._heap, _Queued(t, next(self._seq), frame))
        return True

    def watermark(self, now: float) -> float:
        """Return the capture time up to which every source heard from within the window
        has delivered its frames (-inf when none has been heard from)."""
        since = check_time(now) - self.latency
        for source in [k for k, (_, a) in self._sources.items() if a < since - self.latency]:
            del self._sources[source]  # long silent: forgotten
        active = [t for t, a in self._sources.values() if a >= since]
        return min(active) if active else -math.inf

    def pop_ready(self, now: float) -> list[tuple[float, object]]:
        """Return the (t, frame) pairs captured at or before now - latency or the watermark
        (oldest first), and the oldest beyond `limit`."""
        now = check_time(now)
        horizon = max(now - self.latency, min(self.watermark(now), now))
        out: list[tuple[float, object]] = []
        while self._heap and (self._heap[0].t <= horizon or len(self._heap) > self.limit):
            item = heapq.heappop(self._heap)
            out.append((item.t, item.frame))
            self._released = max(self._released, item.t)
        self._released = max(self._released, horizon)
        return out
