"""The offset of a node's clock to the service's, from the times of its requests.

Each request brackets the service's clock: sent at local time s, answered at local time r, the
service's time when it answered was within [lo, hi] (a `Date` header of whole seconds D: uvicorn
refreshes it once a second, so the time lay in [D, D + 2)). Then offset = service - local lies in
[lo - r, hi - s]. The intersection of the recent intervals narrows with samples taken at
different phases of the second (Marzullo's interval intersection, its simplest case); the
estimate is its middle. An answer that gives the service's time exactly (X-Server-Time) is the
interval [t - r, t - s] of the round trip alone. An empty intersection means a clock stepped:
start again from the newest sample.
"""

from __future__ import annotations

from collections import deque


class ClockOffset:
    """Offset (s) to add to the local clock to get the service's."""

    def __init__(self, window: int = 120) -> None:
        self._samples: deque[tuple[float, float]] = deque(maxlen=window)
        self._lo = -float("inf")
        self._hi = float("inf")

    def add(self, sent: float, received: float, service_lo: float, service_hi: float) -> None:
        """Add one request: local send and receive times and the bounds of the service's time
        in between."""
        interval = (service_lo - received, service_hi - sent)
        self._samples.append(interval)
        lo = max(a for a, _ in self._samples)
        hi = min(b for _, b in self._samples)
        if lo > hi:  # a clock stepped: the old samples describe another offset
            self._samples.clear()
            self._samples.append(interval)
            lo, hi = interval
        self._lo, self._hi = lo, hi

    @property
    def known(self) -> bool:
        """Whether a sample was added."""
        return bool(self._samples)

    @property
    def offset(self) -> float:
        """Return the offset estimate (s), 0 before any sample."""
        return 0.5 * (self._lo + self._hi) if self._samples else 0.0

    @property
    def uncertainty(self) -> float:
        """Return the half-width of the interval the offset lies in (s; inf before any)."""
        return 0.5 * (self._hi - self._lo) if self._samples else float("inf")
