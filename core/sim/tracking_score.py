"""The score of a tracker's reports against the twin's truth, by the standard MOT metrics.

`TrackLog` records what the tracker reports; `score_tracks` uses py-motmetrics (the CLEAR MOT
metrics of Bernardin & Stiefelhagen 2008 and IDF1 of Ristani et al. 2016) at `SCORE_HZ` truth
instants (`truth_instants`) with a `MATCH_DISTANCE_M` match distance, each track answering with
its point nearest in time (within `POINT_TOLERANCE_S`): MOTA, IDF1, identity switches, the most
live (confirmed or coasting) tracks at any instant, and the RMSE of matched positions.
`transformed` moves a log by a planar transform (core.sim.network_cameras.frame_alignment).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from core.localization.tracking import FrameResult, TrackState
from core.sim.crowd import walkers_at
from core.sim.scene import Scene

Array = NDArray[np.float64]

# Scoring: truth instants per second, match distance (m), a track point's time tolerance (s).
SCORE_HZ = 10.0
MATCH_DISTANCE_M = 0.5
POINT_TOLERANCE_S = 0.06


@dataclass
class TrackLog:
    """Collects a tracker's reports: each track's points while it is confirmed (t, x, y, vx,
    vy), the time it was first confirmed and the time it ended."""

    points: dict[int, list[tuple[float, ...]]] = field(default_factory=dict)
    confirmed_at: dict[int, float] = field(default_factory=dict)
    ended_at: dict[int, float] = field(default_factory=dict)

    def add(self, result: FrameResult) -> None:
        """Record one frame's updates and ended tracks."""
        for snap in result.updated:
            if snap.state is TrackState.CONFIRMED:
                self.confirmed_at.setdefault(snap.id, snap.t)
                self.points.setdefault(snap.id, []).append((snap.t, *(float(v) for v in snap.x)))
        for snap in result.ended:
            self.ended_at[snap.id] = result.t

    def end(self, ended: Iterable[Any], t: float) -> None:
        """Record tracks that ended at time t without a frame (Tracker.advance)."""
        for snap in ended:
            self.ended_at[snap.id] = t


def transformed(log: TrackLog, T: Array) -> TrackLog:
    """Return `log` with its points (t, x, y[, vx, vy]) moved by the planar transform T."""
    R, t = T[:2, :2], T[:2, 2]
    points: dict[int, list[tuple[float, ...]]] = {}
    for k, pts in log.points.items():
        arr = np.asarray(pts, dtype=np.float64).reshape(len(pts), -1)
        out = arr.copy()
        out[:, 1:3] = arr[:, 1:3] @ R.T + t
        if arr.shape[1] >= 5:
            out[:, 3:5] = arr[:, 3:5] @ R.T
        points[k] = [tuple(row) for row in out.tolist()]
    return TrackLog(points, dict(log.confirmed_at), dict(log.ended_at))


@dataclass(frozen=True)
class TrackingScore:
    """The MOT metrics of a run: MOTA, IDF1, identity switches, false positives, misses,
    matches, the most live tracks at one instant, and the RMSE (m) of matched positions (all,
    and of the bodies `score_tracks` was asked about)."""

    mota: float
    idf1: float
    id_switches: int
    false_positives: int
    misses: int
    matches: int
    max_live_targets: int
    rmse_m: float
    class_rmse_m: float


def score_tracks(
    truth_t: Array,
    truth_xy: Array,
    log: TrackLog,
    *,
    match_distance: float = MATCH_DISTANCE_M,
    classes: NDArray[np.int64] | None = None,
    truth_at: Callable[[Array], Array] | None = None,
    predict_within: float | None = None,
    rmse_where: NDArray[np.bool_] | None = None,
) -> TrackingScore:
    """Return the MOT metrics of the tracks in `log` against the truth.

    truth_t: (N,) instants (s); truth_xy: (N, B, 2) the B bodies' floor positions (m), NaN
    where a body is not to be tracked. At each instant every live track (confirmed at or
    before it, not ended) answers with its point nearest in time within `POINT_TOLERANCE_S`;
    matching uses squared Euclidean distances gated at match_distance (motmetrics).
    `class_rmse_m` is the RMSE over the matches of the bodies in `classes` (all when None).
    With `truth_at` (times (N,) -> positions (N, B, 2)) the RMSE compares each matched point
    with the truth at the point's own time rather than at the instant it answers for. With
    `predict_within` (s) a track answers instead with its latest point at most that old,
    moved on by its velocity to the instant (what a live display shows between updates of
    cameras slower than the scoring rate); its points must then carry (t, x, y, vx, vy).
    `rmse_where` (N, B) limits the class RMSE to those (instant, body) pairs.
    """
    import motmetrics as mm  # a scoring dependency, loaded only when scoring

    acc = mm.MOTAccumulator(auto_id=True)
    series = {tid: np.asarray(pts, dtype=np.float64) for tid, pts in log.points.items() if len(pts)}
    ids = np.array(sorted(series), dtype=np.int64)
    start = np.array([log.confirmed_at.get(int(i), np.inf) for i in ids])
    stop = np.array([log.ended_at.get(int(i), np.inf) for i in ids])
    max_live = 0
    answered: list[dict[int, Array]] = []  # per instant: track id -> its point (t, x, y)
    point_of: dict[int, Array] = {}
    for k, tau in enumerate(truth_t):
        live = ids[(start <= tau) & (tau < stop)]
        max_live = max(max_live, int(live.size))
        hyp_ids, hyp_xy = [], []
        for tid in live.tolist():
            pts = series[tid]
            if predict_within is not None:
                j = int(np.searchsorted(pts[:, 0], tau, side="right")) - 1
                if j >= 0 and tau - pts[j, 0] <= predict_within:
                    xy = pts[j, 1:3] + pts[j, 3:5] * (tau - pts[j, 0])
                    hyp_ids.append(tid)
                    hyp_xy.append(xy)
                    point_of[tid] = pts[j, :3]  # the RMSE takes the update at its own time
                continue
            j = int(np.searchsorted(pts[:, 0], tau))
            best = None
            for c in (j - 1, j):
                if 0 <= c < len(pts) and abs(pts[c, 0] - tau) <= POINT_TOLERANCE_S:
                    if best is None or abs(pts[c, 0] - tau) < abs(pts[best, 0] - tau):
                        best = c
            if best is not None:
                hyp_ids.append(tid)
                hyp_xy.append(pts[best, 1:3])
                point_of[tid] = pts[best, :3]
        answered.append(dict(point_of))
        point_of.clear()
        present = np.flatnonzero(np.all(np.isfinite(truth_xy[k]), axis=1))
        gt = truth_xy[k, present]
        hyp = np.asarray(hyp_xy, dtype=np.float64).reshape(-1, 2)
        dist = mm.distances.norm2squared_matrix(gt, hyp, max_d2=match_distance**2)
        acc.update(present.tolist(), hyp_ids, dist)
    mh = mm.metrics.create()
    summary = mh.compute(
        acc,
        metrics=[
            "mota",
            "idf1",
            "num_switches",
            "num_false_positives",
            "num_misses",
            "num_matches",
        ],
        name="run",
    )
    row = summary.loc["run"]
    events = acc.mot_events
    matched = events[events["Type"] == "MATCH"]
    d2 = matched["D"].to_numpy(dtype=np.float64)
    if truth_at is not None and len(matched):
        frame = matched.index.get_level_values(0).to_numpy()
        oid = matched["OId"].to_numpy(dtype=np.int64)
        hid = matched["HId"].to_numpy(dtype=np.int64)
        pts = np.array([answered[f][h] for f, h in zip(frame, hid, strict=True)])
        true = truth_at(pts[:, 0])[np.arange(len(pts)), oid]
        d2 = np.sum((pts[:, 1:] - true) ** 2, axis=1)
    rmse = float(np.sqrt(np.mean(d2))) if d2.size else float("nan")
    mine = np.ones(len(matched), dtype=bool)
    if classes is not None:
        mine &= matched["OId"].isin([int(c) for c in classes]).to_numpy()
    if rmse_where is not None and len(matched):
        frame = matched.index.get_level_values(0).to_numpy()
        mine &= rmse_where[frame, matched["OId"].to_numpy(dtype=np.int64)]
    d2c = d2[mine]
    class_rmse = float(np.sqrt(np.mean(d2c))) if d2c.size else float("nan")
    return TrackingScore(
        mota=float(row["mota"]),
        idf1=float(row["idf1"]),
        id_switches=int(row["num_switches"]),
        false_positives=int(row["num_false_positives"]),
        misses=int(row["num_misses"]),
        matches=int(row["num_matches"]),
        max_live_targets=max_live,
        rmse_m=rmse,
        class_rmse_m=class_rmse,
    )


def truth_instants(scene: Scene, duration_s: float) -> tuple[Array, Array]:
    """Return the scoring instants (N,) and the walkers' positions there (N, B, 2)."""
    t = np.arange(0.0, duration_s, 1.0 / SCORE_HZ)
    return t, walkers_at(scene, t)
