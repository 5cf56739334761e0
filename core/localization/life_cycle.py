"""A track's life cycle by elapsed time (core.localization.tracking, "Life cycle"): tentative
tracks confirmed (and then perhaps recognised as a lost body) or dropped, confirmed tracks
coasting, and coasting tracks ending; what ended or was dropped leaves the table."""

from __future__ import annotations

import numpy as np

from core.localization.association import largest_variance
from core.localization.looks import TrackLooks
from core.localization.recognition import recognised, take_over
from core.localization.track_table import TrackTable
from core.localization.tracker_config import CONFIRM_GAPS, TENTATIVE_GAPS, TrackerConfig
from core.localization.tracks import TrackSnapshot, TrackState


def move_life_cycle(
    tracks: TrackTable, looks: TrackLooks, cfg: TrackerConfig, t: float
) -> tuple[tuple[TrackSnapshot, ...], tuple[int, ...], list[int]]:
    """Move the life cycle on at time t (s); return (ended, dropped ids, ids of the lost
    tracks recognised in a newly confirmed one, which go on in its place)."""
    keep = np.ones(len(tracks), dtype=bool)
    ended: list[TrackSnapshot] = []
    dropped: list[int] = []
    found: list[int] = []
    gap = tracks.gap
    for i, st in enumerate(tracks.states):
        silent = t - tracks.last[i]
        if st is TrackState.TENTATIVE:
            if tracks.hits[i] >= cfg.confirm_hits and tracks.score[i] >= cfg.confirm_score:
                tracks.states[i] = TrackState.CONFIRMED
                j = recognised(tracks, looks, i, cfg)
                if j is not None:
                    take_over(tracks, looks, j, i)
                    found.append(tracks.ids[j])
                    keep[i] = False
                    dropped.append(tracks.ids[i])
            elif (
                t - tracks.first[i] > max(cfg.confirm_window, CONFIRM_GAPS * gap[i])
                or silent > max(cfg.tentative_timeout, TENTATIVE_GAPS * gap[i])
                or tracks.score[i] < cfg.drop_score
            ):
                keep[i] = False
                dropped.append(tracks.ids[i])
            continue
        if silent > cfg.coast_after:
            tracks.states[i] = TrackState.COASTING
        if tracks.states[i] is TrackState.COASTING:
            worst = float(largest_variance(tracks.P[i, :2, :2]))
            if tracks.labels[i] is not None:
                # A labelled body is known by its label, not found by its position: its
                # track waits for the label to come back however vague it has become.
                over = silent > cfg.labelled_end_after
            elif tracks.ids[i] in looks:
                # A body with a look may be recognised by it (core.localization.recognition).
                over = silent > cfg.end_after
            else:
                over = silent > cfg.end_after or worst > cfg.max_position_std**2
            if over:
                tracks.states[i] = TrackState.ENDED
                ended.append(tracks.snapshot(i, tracks.x, tracks.P, t))
                keep[i] = False
    if not keep.all():
        tracks.keep(np.flatnonzero(keep))
        looks.forget((*dropped, *(snap.id for snap in ended)))
    return tuple(ended), tuple(dropped), found
