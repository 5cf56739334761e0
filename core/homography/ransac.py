"""LO-RANSAC for homographies (Chum, Matas & Kittler 2003): exact four-point homographies of
minimal samples, scored by the truncated dst transfer error (MSAC), the DLT refitted on the
consensus set of every new best model, and an adaptive sample count.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from core.errors import DegenerateConfiguration
from core.homography.dlt import _dlt_normalized
from core.homography.normalization import _normalize_t, _triple_dets

Array = NDArray[np.float64]

# A RANSAC minimal sample whose point triples have |det| below this (normalised coordinates,
# where a well-spread triple has |det| ~ 1) is too close to collinear to give a useful model.
_SAMPLE_DET_TOL = 1e-6
# Hypotheses x points scored per numpy call in RANSAC: large enough to amortise the call
# overhead, small enough to keep the (K, 3, N) temporaries in cache-friendly sizes.
_RANSAC_BATCH_ELEMENTS = 400_000


@dataclass(frozen=True)
class _Consensus:
    inliers: NDArray[np.bool_]
    samples: int


def _basis_maps(p: Array) -> Array:
    """Return B (K, 3, 3) mapping e1, e2, e3, (1,1,1) to the four points of each sample
    (columns p1, p2, p3 scaled by lambda with [p1 p2 p3] lambda = p4); requires no three
    points collinear."""
    ph = np.concatenate([p, np.ones((*p.shape[:2], 1))], axis=2)  # (K, 4, 3)
    a = ph[:, :3].transpose(0, 2, 1)
    lam = np.linalg.solve(a, ph[:, 3, :, None])[:, :, 0]
    return a * lam[:, None, :]


def _four_point_homographies(ps: Array, pd: Array) -> tuple[Array, NDArray[np.bool_]]:
    """Return (H (K, 3, 3), valid (K,)) with pd ~ H ps exactly for every minimal sample.

    Samples with a (nearly) collinear triple on either side, or whose triples change orientation
    inconsistently (impossible for points in front of a camera), are invalid.
    """
    ds, dd = _triple_dets(ps), _triple_dets(pd)
    prod = ds * dd
    valid = np.all(np.abs(ds) > _SAMPLE_DET_TOL, axis=1) & np.all(
        np.abs(dd) > _SAMPLE_DET_TOL, axis=1
    )
    valid &= np.all(prod > 0, axis=1) | np.all(prod < 0, axis=1)
    ps = np.where(valid[:, None, None], ps, _UNIT_SQUARE)
    pd = np.where(valid[:, None, None], pd, _UNIT_SQUARE)
    bs, bd = _basis_maps(ps), _basis_maps(pd)
    # H = Bd Bs^-1, solved as Bs^T H^T = Bd^T.
    h = np.linalg.solve(bs.transpose(0, 2, 1), bd.transpose(0, 2, 1)).transpose(0, 2, 1)
    return np.asarray(h, np.float64), valid


_UNIT_SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def _transfer_errors2(h: Array, ps_h: Array, pd_t: Array) -> Array:
    """Return (K, N) squared dst transfer errors of hypotheses h (K, 3, 3); ps_h (3, N) are the
    homogeneous src points, pd_t (2, N) the dst points. Points mapped to infinity get an
    infinite error."""
    ph = h @ ps_h  # (K, 3, N)
    w = ph[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_w = 1.0 / w
        du = ph[:, 0] * inv_w - pd_t[0]
        dv = ph[:, 1] * inv_w - pd_t[1]
        e2 = du * du + dv * dv
    return np.where(np.isfinite(e2), e2, np.inf)


def _required_samples(inlier_ratio: float, confidence: float) -> float:
    """Return the number of minimal samples for `confidence` of one all-inlier sample."""
    w4 = inlier_ratio**4
    if w4 >= 1.0:
        return 0.0
    if w4 <= 0.0:
        return np.inf
    return float(np.log1p(-confidence) / np.log1p(-w4))


def _lo_ransac(
    s: Array,
    d: Array,
    threshold: float,
    confidence: float,
    max_samples: int,
    rng: np.random.Generator,
) -> _Consensus:
    """Return the consensus set of LO-RANSAC (Chum, Matas & Kittler, DAGM 2003) with MSAC
    scoring (Torr & Zisserman 2000): the truncated squared dst transfer error."""
    n = len(s)
    _, ps_t = _normalize_t(s, "src")
    Td, pd_t = _normalize_t(d, "dst")
    ps, pd = ps_t.T, pd_t.T
    thr2 = (threshold * Td[0, 0]) ** 2
    ps_h = np.vstack([ps_t, np.ones(n)])
    # Batches start small (32 samples already find an all-inlier one with 99.98 % probability
    # at 70 % inliers) and double while more are needed, up to a memory-bounded size.
    max_batch = int(np.clip(_RANSAC_BATCH_ELEMENTS // n, 8, 512))
    batch = min(32, max_batch)

    best_score = np.inf
    best_mask = np.zeros(n, dtype=bool)
    needed = float(max_samples)
    drawn = 0
    while drawn < min(needed, max_samples):
        k = int(min(batch, max_samples - drawn))
        batch = min(2 * batch, max_batch)
        idx = rng.integers(0, n, size=(k, 4))
        drawn += k
        srt = np.sort(idx, axis=1)
        idx = idx[np.all(srt[:, 1:] != srt[:, :-1], axis=1)]
        if len(idx) == 0:
            continue
        hyps, valid = _four_point_homographies(ps[idx], pd[idx])
        hyps = hyps[valid]
        if len(hyps) == 0:
            continue
        e2 = _transfer_errors2(hyps, ps_h, pd_t)
        scores = np.minimum(e2, thr2).sum(axis=1)
        j = int(np.argmin(scores))
        if scores[j] >= best_score:
            continue
        best_score = float(scores[j])
        best_mask = e2[j] < thr2
        # Local optimisation: refit on the consensus set while the score improves.
        for _ in range(5):
            if np.count_nonzero(best_mask) < 5:
                break
            try:
                h_lo = _dlt_normalized(ps_t[:, best_mask], pd_t[:, best_mask])
            except DegenerateConfiguration:
                break
            e2_lo = _transfer_errors2(h_lo[None], ps_h, pd_t)[0]
            score_lo = float(np.minimum(e2_lo, thr2).sum())
            if score_lo >= best_score:
                break
            best_score = score_lo
            best_mask = e2_lo < thr2
        needed = _required_samples(np.count_nonzero(best_mask) / n, confidence)

    if np.count_nonzero(best_mask) < 4:
        raise DegenerateConfiguration(
            "RANSAC found no model with 4 or more inliers; raise ransac_threshold or check the "
            "correspondences"
        )
    return _Consensus(inliers=best_mask, samples=drawn)
