"""The offset of a node's clock to the service's, from the times of its requests; the delays
of a node's stages.

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

import threading
from collections import deque

import numpy as np


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


class StageDelays:
    """The recent delays (s) of a pipeline's stages, one row per frame, and their percentiles."""

    def __init__(self, stages: tuple[str, ...], keep: int = 20_000) -> None:
        self.stages = stages
        self._rows: deque[tuple[float, ...]] = deque(maxlen=keep)
        self._lock = threading.Lock()

    def __len__(self) -> int:
        with self._lock:
            return len(self._rows)

    def add(self, *delays: float) -> None:
        """Record one frame's delay in each stage (s), in the order of `stages`."""
        if len(delays) != len(self.stages):
            raise ValueError(f"{len(self.stages)} delays expected, got {len(delays)}")
        with self._lock:
            self._rows.append(tuple(float(d) for d in delays))

    def percentiles(self, q: float) -> dict[str, float]:
        """Return each stage's q-th percentile delay (s); NaN before any frame."""
        with self._lock:
            rows = np.array(self._rows, dtype=np.float64).reshape(-1, len(self.stages))
        if not rows.shape[0]:
            return dict.fromkeys(self.stages, float("nan"))
        return dict(zip(self.stages, np.percentile(rows, q, axis=0).tolist(), strict=True))

    def describe(self) -> str:
        """Return the stages' p50 and p95 delays as one line of text."""
        p50, p95 = self.percentiles(50), self.percentiles(95)
        stages = ", ".join(
            f"{k} p50 {1000 * p50[k]:.0f} ms p95 {1000 * p95[k]:.0f} ms" for k in self.stages
        )
        return f"{len(self)} frames; {stages}"
