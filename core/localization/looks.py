"""What a tracker remembers of each track's look (core.localization.tracking, "Appearance"):
per track and camera, the running mean of the appearance descriptors
(core.localization.appearance) of the detections that updated it, and where the track was at
its last update, for recognising its body after it was lost."""

from __future__ import annotations

from collections.abc import Hashable, Iterable, Sequence

import numpy as np
from numpy.typing import NDArray

from core.localization.appearance import appearance_distance

Array = NDArray[np.float64]


class TrackLooks:
    """The looks of a tracker's tracks, by track id; `rate`: the weight of each new descriptor
    in a track's running mean (0-1]."""

    def __init__(self, rate: float) -> None:
        self.rate = rate
        self._mean: dict[int, dict[Hashable, Array]] = {}
        self._where: dict[int, Array] = {}

    def __contains__(self, track: int) -> bool:
        return track in self._mean

    def distances(self, tracks: Sequence[int], camera: Hashable, looks: Array) -> Array:
        """Return the appearance distance (T, D) between each track's look in `camera` and
        each descriptor of `looks` (D, F); NaN where the track has no look there (or one of
        another length) or the descriptor is all zeros."""
        out = np.full((len(tracks), looks.shape[0]), np.nan)
        has = np.flatnonzero(looks.sum(axis=1) > 0)
        rows = [
            k
            for k, tid in enumerate(tracks)
            if camera in self._mean.get(tid, {})
            and self._mean[tid][camera].shape == looks.shape[1:]
        ]
        if rows and has.size:
            means = np.array([self._mean[tracks[k]][camera] for k in rows])
            out[np.ix_(np.array(rows, dtype=np.intp), has)] = appearance_distance(means, looks[has])
        return out

    def learn(self, track: int, camera: Hashable, look: Array, xy: Array) -> None:
        """Move the track's look in `camera` towards the descriptor `look` (F,) of a
        detection that updated it at floor position `xy` (2,) (a track's first look is taken
        as it is); an all-zero descriptor says nothing of the look."""
        if not look.sum() > 0:
            return
        mine = self._mean.setdefault(track, {})
        old = mine.get(camera)
        if old is None or old.shape != look.shape:
            mine[camera] = look.copy()
        else:
            mine[camera] = old + self.rate * (look - old)
        self._where[track] = np.array(xy[:2], dtype=np.float64)

    def moved(self, track: int, xy: Array) -> None:
        """Record that a track with a look was updated at floor position `xy` (2,)."""
        if track in self._mean:
            self._where[track] = np.array(xy[:2], dtype=np.float64)

    def last_position(self, track: int) -> Array | None:
        """Return where the track was at its last update since it had a look, or None."""
        return self._where.get(track)

    def distance(self, a: int, b: int) -> float | None:
        """Return the smallest appearance distance between tracks a and b over the cameras
        that saw both (looks of one camera only are comparable), None when none did."""
        mine, theirs = self._mean.get(a, {}), self._mean.get(b, {})
        common = [c for c in mine if c in theirs and theirs[c].shape == mine[c].shape]
        if not common:
            return None
        return min(float(appearance_distance(mine[c][None], theirs[c][None])[0, 0]) for c in common)

    def inherit(self, heir: int, source: int) -> None:
        """Let track `heir` take the looks of track `source` (the same body: its newer
        looks replace, camera by camera) and where it was last."""
        self._mean.setdefault(heir, {}).update(self._mean.get(source, {}))
        if source in self._where:
            self._where[heir] = self._where[source]

    def forget(self, tracks: Iterable[int]) -> None:
        """Forget the looks of tracks that left the tracker."""
        for tid in tracks:
            self._mean.pop(tid, None)
            self._where.pop(tid, None)
