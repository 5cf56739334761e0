"""Tracks started at detections (core.localization.tracking, "Life cycle"): tentative tracks born
at the detections no track takes and that no existing body explains, the misses that lower
their score, by each camera that had one in view and did not detect it, and a track too vague
to update started again at its detection."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from core.localization._projection import project_plane, transposed
from core.localization.association import mahalanobis
from core.localization.cameras import NetworkCamera
from core.localization.ground import locate_monocular
from core.localization.looks import TrackLooks
from core.localization.occluders import Occluders, line_of_sight
from core.localization.occlusion import behind_a_body, visible
from core.localization.recognition import waiting
from core.localization.track_table import TrackTable
from core.localization.tracker_config import TrackerConfig
from core.localization.tracks import TrackState

Array = NDArray[np.float64]


def births(
    cam: NetworkCamera,
    tracks: TrackTable,
    looks: TrackLooks,
    occluders: Occluders | None,
    cfg: TrackerConfig,
    detections: tuple[Array, Array, Array, list[str], list[str | None]],
    free: NDArray[np.intp],
    *,
    t: float,
    gap: float,
    next_id: int,
) -> list[tuple[int, int]]:
    """Start tentative tracks at time t (s) at the free detections (`detections`: pixels,
    covariances, heights, kinds and labels) that are no existing body; return (detection
    index, new id) pairs, the ids counting on from `next_id` (`gap`: the camera's frame
    interval). The most precise detections go first, each checked against every track, those
    it just started included."""
    px, R, h, kind, lab = detections
    xy = np.full((px.shape[0], 2), np.nan)
    C = np.broadcast_to(np.eye(2), (px.shape[0], 2, 2)).copy()
    for value in np.unique(h[free]):
        sel = free[h[free] == value]
        est = locate_monocular(cam, px[sel], float(value), pixel_cov=R[sel])
        v = est.valid
        xy[sel[v]] = est.xy[v]
        C[sel[v]] = est.cov[v]
    out: list[tuple[int, int]] = []
    order = free[np.argsort(np.linalg.det(R[free]), kind="stable")]
    for j in order.tolist():
        if not np.all(np.isfinite(xy[j])):
            continue
        if lab[j] is not None and lab[j] in tracks.labels:
            continue
        if tracks.ids and lab[j] is None:
            # Only a body this camera can see may have made this blob as its outlier.
            T = len(tracks)
            near = (
                visible(cam, tracks, occluders, cfg) if occluders is not None else np.ones(T, bool)
            )
            # A lost track waiting to be recognised (core.localization.recognition) stands
            # nowhere.
            near &= ~waiting(tracks, looks, np.arange(T), cfg)
            diff = xy[j] - tracks.x[near, :2]
            if np.any(np.einsum("ij,ij->i", diff, diff) < cfg.min_separation**2):
                continue
            d2, _ = mahalanobis(diff, tracks.P[near, :2, :2] + C[j])
            if np.any(d2 <= cfg.birth_gate):
                continue
        tid = next_id + len(out)
        _birth(tracks, cfg, tid, xy[j], C[j], kind[j], lab[j], float(h[j]), t, gap)
        out.append((j, tid))
    return out


def _start(xy: Array, C: Array, cfg: TrackerConfig) -> tuple[Array, Array]:
    """Return the state (4,) and covariance (4, 4) of a body at `xy` (2,) with covariance C
    (2, 2), its speed unknown: N(0, initial_speed_std^2) per axis."""
    x = np.array([xy[0], xy[1], 0.0, 0.0])
    P = np.zeros((4, 4))
    P[:2, :2] = C
    P[2, 2] = P[3, 3] = cfg.initial_speed_std**2
    return x, P


def _birth(
    tracks: TrackTable,
    cfg: TrackerConfig,
    tid: int,
    xy: Array,
    C: Array,
    kind: str,
    label: str | None,
    height: float,
    t: float,
    gap: float,
) -> None:
    x, P = _start(xy, C, cfg)
    tracks.x = np.concatenate([tracks.x, x[None]])
    tracks.P = np.concatenate([tracks.P, P[None]])
    # A label is an identity the sender is sure of: nothing left to confirm.
    confirmed = cfg.confirm_hits <= 1 or label is not None
    state = TrackState.CONFIRMED if confirmed else TrackState.TENTATIVE
    tracks.append(tid, kind, label, state, hits=1, first=t, last=t, height=height, moved=t, gap=gap)


def restart(
    cam: NetworkCamera,
    tracks: TrackTable,
    rows: NDArray[np.intp],
    detections: tuple[Array, Array, Array],
    cols: NDArray[np.intp],
    cfg: TrackerConfig,
) -> None:
    """Put tracks `rows` at the back-projections of their detections `cols` (of `detections`:
    pixels, covariances and heights), speed unknown, keeping their ids: a labelled body back
    after a long absence, its track too vague to linearise about."""
    px, R, h = detections
    for i, j in zip(rows.tolist(), cols.tolist(), strict=True):
        est = locate_monocular(cam, px[j][None], float(h[j]), pixel_cov=R[j][None])
        if not est.valid[0]:
            continue
        tracks.x[i], tracks.P[i] = _start(est.xy[0], est.cov[0], cfg)


def score_misses(
    cam: NetworkCamera,
    tracks: TrackTable,
    looks: TrackLooks,
    occluders: Occluders | None,
    cfg: TrackerConfig,
    hit: NDArray[np.bool_],
    vague: tuple[Array, Array, Array],
) -> None:
    """Add ln(1 - p_D) to the score of each tentative track that this camera has in view
    (at the height of its last detection, not hidden by the occluders nor by another body:
    core.localization.occlusion) but did not detect in this frame (`hit`: the tracks it
    did). A track inside the gate of a detection left out as too vague (`vague`: its pixels,
    covariances and heights) was seen, only not placed: no miss either."""
    idx = [i for i in range(hit.size) if not hit[i] and tracks.states[i] is TrackState.TENTATIVE]
    if not idx:
        return
    rows = np.asarray(idx, dtype=np.intp)
    heights = np.asarray([tracks.height[i] for i in idx])
    pts = np.column_stack([tracks.x[rows, :2], heights])
    seen = cam.in_view(pts)
    if occluders is not None and seen.any():
        seen[seen] = line_of_sight(cam.center[None], pts[seen], occluders)[0]
    if seen.any():
        lost = waiting(tracks, looks, np.arange(len(tracks)), cfg)
        seen[seen] = ~behind_a_body(cam, tracks, rows[seen], lost, cfg)
    v_px, v_R, v_h = vague
    if seen.any() and v_px.shape[0]:
        for value in np.unique(v_h):
            sel = np.flatnonzero(v_h == value)
            look = rows[seen]
            proj = project_plane(cam, tracks.x[look, :2], float(value), jacobian=True)
            assert proj.jacobian is not None
            J = proj.jacobian
            S = J[:, None] @ tracks.P[look][:, None, :2, :2] @ transposed(J)[:, None]
            d2, _ = mahalanobis(v_px[sel][None] - proj.pixels[:, None], S + v_R[sel][None])
            inside = np.any(np.nan_to_num(d2, nan=np.inf) <= cfg.gate, axis=1)
            seen[np.flatnonzero(seen)[inside]] = False
    miss = math.log(1.0 - cfg.p_detect)
    for i in rows[seen].tolist():
        tracks.score[i] += miss
