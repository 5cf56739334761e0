"""Recognising a lost body by its look (core.localization.tracking, "Appearance"): which tracks
are lost and wait to be recognised, which of them a newly confirmed track is the body of, and
the lost track's going on as that body under its old id."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from core.localization.association import largest_variance
from core.localization.looks import TrackLooks
from core.localization.track_table import TrackTable
from core.localization.tracker_config import WALKING_SPEED, TrackerConfig
from core.localization.tracks import TrackState


def waiting(
    tracks: TrackTable, looks: TrackLooks, rows: NDArray[np.intp], cfg: TrackerConfig
) -> NDArray[np.bool_]:
    """Return whether each track of `rows` is lost and waiting to be recognised by its
    look: unlabelled, with a look, too vague to say where its body is."""
    has_look = np.array(
        [tracks.ids[i] in looks and tracks.labels[i] is None for i in rows.tolist()],
        dtype=bool,
    )
    return has_look & tracks.vague(rows, cfg.max_position_std)


def recognised(tracks: TrackTable, looks: TrackLooks, i: int, cfg: TrackerConfig) -> int | None:
    """Return the lost track (`waiting`) that the newly confirmed track i is the body
    of, or None: of those whose look in a camera both were seen by lies within
    recognition_distance of track i's and which could have walked to track i's position since
    their last update, the nearest in look."""
    if tracks.ids[i] not in looks:
        return None
    rows = np.arange(len(tracks))
    lost = waiting(tracks, looks, rows, cfg)
    best, best_d = None, cfg.recognition_distance
    for j in np.flatnonzero(lost).tolist():
        if j == i or tracks.kinds[j] not in (tracks.kinds[i], "unknown"):
            continue
        d = looks.distance(tracks.ids[i], tracks.ids[j])
        was = looks.last_position(tracks.ids[j])
        if d is None or was is None or d > best_d:
            continue
        # A walker covers at most WALKING_SPEED in each second since the lost track's last
        # update, plus three standard deviations of where the new track puts them.
        reach = WALKING_SPEED * (tracks.first[i] - tracks.last[j]) + 3.0 * math.sqrt(
            float(largest_variance(tracks.P[i, :2, :2]))
        )
        if float(np.linalg.norm(tracks.x[i, :2] - was)) <= reach:
            best, best_d = j, d
    return best


def take_over(tracks: TrackTable, looks: TrackLooks, j: int, i: int) -> None:
    """Let lost track j go on as the newly confirmed track i, which it is the body of
    (`recognised`): track j takes track i's state, sightings and looks."""
    tracks.x[j] = tracks.x[i]
    tracks.P[j] = tracks.P[i]
    tracks.states[j] = TrackState.CONFIRMED
    tracks.hits[j] += tracks.hits[i]
    tracks.last[j] = tracks.last[i]
    tracks.moved[j] = tracks.moved[i]
    tracks.height[j] = tracks.height[i]
    tracks.gap[j] = tracks.gap[i]
    looks.inherit(tracks.ids[j], tracks.ids[i])
