"""The recent delays of a pipeline's stages (a node's capture to upload, the service's tracker's
arrival to update), one row per frame, and their percentiles: what a node and the service both
keep and log when they stop."""

from __future__ import annotations

import threading
from collections import deque

import numpy as np


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
