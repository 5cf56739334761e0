"""Live targets and the tracker's snapshots of them: a stored live target read back, and a
live target as the snapshot core Tracker.restore takes (a space taken over keeps its tracks and
their ids)."""

from __future__ import annotations

import re

import numpy as np

from core.localization.tracking import TrackerConfig, TrackSnapshot, TrackState
from server.db.models import Target
from server.services.targets import LiveTarget

# A target's name when no sender labelled it (LiveTargets.update): kind-space-track.
_AUTO_NAME = re.compile(r"(robot|person|unknown)-(\d+)-(\d+)")


def live_of(row: Target) -> LiveTarget:
    """Return a stored live target as a LiveTarget (speed unknown)."""
    space = row.space_id if row.space_id is not None else 0
    auto = _AUTO_NAME.fullmatch(row.label)
    labelled = auto is None or (int(auto[2]), int(auto[3])) != (space, row.track_id)
    t = float(row.t or 0.0)
    v = LiveTarget(
        row.space_id,
        int(row.track_id or 0),
        row.label,
        row.kind,
        row.state,
        float(row.first_seen if row.first_seen is not None else t),
        float(row.last_seen if row.last_seen is not None else t),
        t,
        [float(c) for c in (row.xy or [0.0, 0.0])],
        [[float(c) for c in r] for r in (row.cov or [[1.0, 0.0], [0.0, 1.0]])],
    )
    v.id, v.labelled = row.id, labelled
    return v


def snapshot_of(v: LiveTarget, config: TrackerConfig) -> TrackSnapshot:
    """Return a live target as the tracker's snapshot, for Tracker.restore: its full state
    covariance when its tracker sent it, else its position's with an unknown speed (zero,
    the prior's variance)."""
    if v.state_cov is not None:
        x = np.array([v.xy[0], v.xy[1], v.velocity[0], v.velocity[1]], dtype=np.float64)
        P = np.array(v.state_cov, dtype=np.float64)
    else:
        x = np.array([v.xy[0], v.xy[1], 0.0, 0.0], dtype=np.float64)
        P = np.zeros((4, 4))
        P[:2, :2] = np.array(v.cov, dtype=np.float64)
        P[2, 2] = P[3, 3] = config.initial_speed_std**2
    return TrackSnapshot(
        id=v.track_id,
        kind=v.kind,
        label=v.label if v.labelled else None,
        state=TrackState(v.state),
        t=v.t,
        x=x,
        cov=P,
        hits=max(v.hits, 1),
        first_seen=min(v.first_seen, v.last_seen),
        last_seen=min(v.last_seen, v.t),
    )
