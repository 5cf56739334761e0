"""The tracker's tracks as one table (core.localization.tracking): row i of every column is
track i, so the filter works on all tracks at once (states (T, 4), covariances (T, 4, 4)) and
the life cycle keeps or drops whole rows."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from core.localization.association import largest_variance
from core.localization.tracks import TrackSnapshot, TrackState

Array = NDArray[np.float64]

# The per-track columns besides the state and covariance, in the order rows are kept.
_COLUMNS = (
    "ids",
    "kinds",
    "labels",
    "states",
    "hits",
    "first",
    "last",
    "score",
    "height",
    "moved",
    "gap",
)


class TrackTable:
    """The tracks of one tracker, row by row: `x` (T, 4) the states (x, y, vx, vy), `P`
    (T, 4, 4) their covariances, and per track its id, kind, label, life-cycle state, number of
    updates (`hits`), time of its first and last update, tentative score (log-likelihood
    ratio), height of its last detection (m), time of the last update that moved its state
    (`moved`) and the frame interval of the camera that last updated it (`gap`, s)."""

    def __init__(self) -> None:
        self.x = np.zeros((0, 4))
        self.P = np.zeros((0, 4, 4))
        self.ids: list[int] = []
        self.kinds: list[str] = []
        self.labels: list[str | None] = []
        self.states: list[TrackState] = []
        self.hits: list[int] = []
        self.first: list[float] = []
        self.last: list[float] = []
        self.score: list[float] = []
        self.height: list[float] = []
        self.moved: list[float] = []
        self.gap: list[float] = []

    def __len__(self) -> int:
        return len(self.ids)

    def append(
        self,
        tid: int,
        kind: str,
        label: str | None,
        state: TrackState,
        *,
        hits: int,
        first: float,
        last: float,
        height: float,
        moved: float,
        gap: float,
    ) -> None:
        """Add one track's row to the lists (its state and covariance go in `x` and `P`
        separately, so that several tracks join the arrays at once); its score starts at 0."""
        self.ids.append(tid)
        self.kinds.append(kind)
        self.labels.append(label)
        self.states.append(state)
        self.hits.append(hits)
        self.first.append(first)
        self.last.append(last)
        self.score.append(0.0)
        self.height.append(height)
        self.moved.append(moved)
        self.gap.append(gap)

    def keep(self, idx: NDArray[np.intp]) -> None:
        """Keep the rows `idx` (in that order) and drop the others."""
        self.x = self.x[idx]
        self.P = self.P[idx]
        for name in _COLUMNS:
            old = getattr(self, name)
            setattr(self, name, [old[i] for i in idx.tolist()])

    def shift(self, dt: float) -> None:
        """Move every track's times on by dt seconds."""
        self.first = [v + dt for v in self.first]
        self.last = [v + dt for v in self.last]
        self.moved = [v + dt for v in self.moved]

    def vague(self, rows: NDArray[np.intp], max_std: float) -> NDArray[np.bool_]:
        """Return whether each track's position standard deviation (larger axis) exceeds
        `max_std` (m)."""
        return largest_variance(self.P[rows, :2, :2]) > max_std**2

    def snapshot(self, i: int, x: Array, P: Array, when: float | None) -> TrackSnapshot:
        """Return track i as a snapshot with state x[i] and covariance P[i] at time `when`."""
        return TrackSnapshot(
            id=self.ids[i],
            kind=self.kinds[i],
            label=self.labels[i],
            state=self.states[i],
            t=float("nan") if when is None else when,
            x=x[i].copy(),
            cov=P[i].copy(),
            hits=self.hits[i],
            first_seen=self.first[i],
            last_seen=self.last[i],
        )
