"""What a tracker says of its tracks: their kinds and life-cycle states, a track's snapshot at
a time, and what one camera frame did (core.localization.tracking)."""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

KINDS = ("robot", "person", "unknown")


class TrackState(StrEnum):
    """A track's stage in its life cycle."""

    TENTATIVE = "tentative"
    CONFIRMED = "confirmed"
    COASTING = "coasting"
    ENDED = "ended"


LIVE_STATES = (TrackState.CONFIRMED, TrackState.COASTING)


@dataclass(frozen=True)
class TrackSnapshot:
    """A track at time t: id, kind, label (None unless a labelled detection started it), life
    cycle state, state (4,) = (x, y, vx, vy) in m and m/s with cov (4, 4), number of updates
    (`hits`), time of the first and of the last update (`first_seen`, `last_seen`)."""

    id: int
    kind: str
    label: str | None
    state: TrackState
    t: float
    x: Array
    cov: Array
    hits: int
    first_seen: float
    last_seen: float

    @property
    def xy(self) -> Array:
        """Position (2,), metres."""
        return self.x[:2]

    @property
    def xy_cov(self) -> Array:
        """Covariance of the position (2, 2), m^2."""
        return self.cov[:2, :2]

    @property
    def velocity(self) -> Array:
        """Velocity (2,), m/s."""
        return self.x[2:]


@dataclass(frozen=True)
class FrameResult:
    """What one camera frame did: `track_ids` (D,) the id of the track each detection updated
    or started (-1: none took it and it started none); `started` (D,) whether it started that
    track; `updated` the snapshots, after the update, of the tracks this frame updated (new
    tentative tracks included); `ended` the tracks that ended at this frame's time; `dropped`
    the ids of tentative tracks dropped unconfirmed."""

    t: float
    camera: Hashable
    track_ids: NDArray[np.int64]
    started: NDArray[np.bool_]
    updated: tuple[TrackSnapshot, ...]
    ended: tuple[TrackSnapshot, ...]
    dropped: tuple[int, ...]
