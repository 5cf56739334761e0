"""Where the landmarks' patterns are in a colour score, and their sub-pixel edges.

A pattern is a thresholded component of its colour score (the channel minus the larger other
one) with a hole; its edges are the score's iso-contour at half the pattern's contrast
(marching squares: where a symmetric blur leaves a straight step edge), one boundary per edge.
"""

from __future__ import annotations

from itertools import pairwise
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
Image = NDArray[Any]

# A pixel belongs to a pattern when its colour score (the channel minus the larger other one)
# exceeds this many grey levels: pure blue or red under gain 0.5 scores ~127, grey 0 +- noise.
SCORE_THRESHOLD = 50
MIN_AREA_PX = 30.0


def holed_components(
    score: Image, scratch: Image, every_pixel: bool = True
) -> list[tuple[Image, Image]]:
    """Return (outer contour, largest hole contour) of every thresholded component with a hole
    (scratch: a plane of score's shape and type, overwritten). The contours list every boundary
    pixel, or with every_pixel False only the ends of their straight runs (the same polygons:
    the same areas, fills, hulls and quadrilaterals, from a fifth of the points)."""
    _, mask = cv2.threshold(score, SCORE_THRESHOLD, 1, cv2.THRESH_BINARY, dst=scratch)
    chain = cv2.CHAIN_APPROX_NONE if every_pixel else cv2.CHAIN_APPROX_SIMPLE
    contours, hier = cv2.findContours(mask, cv2.RETR_CCOMP, chain)
    if hier is None:
        return []
    h = hier[0]
    out = []
    for i, c in enumerate(contours):
        if h[i, 3] != -1 or h[i, 2] == -1 or cv2.contourArea(c) < MIN_AREA_PX:
            continue
        child, best, best_area = h[i, 2], None, 0.0
        while child != -1:
            a = cv2.contourArea(contours[child])
            if a > best_area:
                best, best_area = contours[child], a
            child = h[child, 0]
        if best is not None and best_area >= 4.0:
            out.append((c, best))
    # A component inside another one's hole is part of it (a signpost's inner ring).
    keep = []
    for i, (c, _) in enumerate(out):
        p = tuple(float(v) for v in c[0, 0])
        if not any(
            j != i and cv2.pointPolygonTest(hole, p, False) > 0 for j, (_, hole) in enumerate(out)
        ):
            keep.append(out[i])
    return keep


def bounding_roi(contour: Image, shape: tuple[int, ...], pad: int = 4) -> tuple[int, int, int, int]:
    """Return the contour's bounding box (x0, y0, x1, y1) grown by `pad` pixels, within an image
    of `shape`."""
    x, y, w, h = cv2.boundingRect(contour)
    x0, y0 = max(x - pad, 0), max(y - pad, 0)
    x1, y1 = min(x + w + pad, shape[1]), min(y + h + pad, shape[0])
    return x0, y0, x1, y1


def iso_points(score: Image, roi: tuple[int, int, int, int], inside: Image) -> list[Array]:
    """Return the sub-pixel points (lists of (N, 2) x, y pixels, one list per boundary) where
    the score crosses half the pattern's contrast (its plateau over `inside`, a mask of the
    ROI, and the white page's ~0).

    Each crossing between horizontally or vertically adjacent pixels is placed by linear
    interpolation (the edges marching squares would draw), and labelled by the region below
    the level it borders (8-connected: the outside, a frame's hole, the gap between two rings,
    their centre) and by its side (the pattern's pixel nearer the pattern's centre than the
    white one, or farther): one boundary per label, e.g. a frame's outer and inner edges, or
    the four ring edges (the gap between the rings borders two of them, one on each side).
    A thin band broken by the threshold into pieces still gives one boundary per edge."""
    x0, y0, x1, y1 = roi
    roi_score = score[y0:y1, x0:x1]
    # The centroid of `inside` from its column and row counts: two reductions where cv2.moments
    # makes a pass per moment; integer sums, so the same value exactly.
    cols = cv2.reduce(inside, 0, cv2.REDUCE_SUM, dtype=cv2.CV_32S).ravel()
    rows = cv2.reduce(inside, 1, cv2.REDUCE_SUM, dtype=cv2.CV_32S).ravel()
    m00 = float(cols.sum())
    if m00 == 0:
        return []
    cx = float(cols @ np.arange(len(cols), dtype=np.float64)) / m00
    cy = float(rows @ np.arange(len(rows), dtype=np.float64)) / m00
    # Half-way between the pattern's plateau (the 90th percentile of the scores over `inside`,
    # linearly interpolated as numpy's percentile, from their histogram: blur lowers thin
    # bands' pixels, and a low level would widen the bands) and the white page around it (~0).
    hist = cv2.calcHist([roi_score], [0], inside, [256], [0, 256]).ravel()
    cum = np.cumsum(hist.astype(np.float64))
    pos = 0.9 * (cum[-1] - 1)
    lo = int(np.floor(pos))
    v_lo, v_hi = np.searchsorted(cum, [lo + 1, min(lo + 2, cum[-1])])
    level = np.float32(0.5 * (v_lo + (pos - lo) * (v_hi - v_lo)))
    # The scores are integers: score > level is score > floor(level), which is what OpenCV's
    # threshold of an 8-bit image tests (one pass each, no floating-point copy of the ROI).
    _, above = cv2.threshold(roi_score, float(level), 1, cv2.THRESH_BINARY)
    _, below = cv2.threshold(roi_score, float(level), 1, cv2.THRESH_BINARY_INV)
    n_labels, lb = cv2.connectedComponents(below, connectivity=8)
    # Exact integer gradients (|Sobel| <= 4 * 255), as the floating-point ones were.
    gxi = cv2.Sobel(roi_score, cv2.CV_16S, 1, 0, ksize=3)
    gyi = cv2.Sobel(roi_score, cv2.CV_16S, 0, 1, ksize=3)
    width = roi_score.shape[1]
    # Each crossing's first pixel (flat index into the ROI; numpy's two-dimensional nonzero is
    # several times slower), between horizontal neighbours then vertical ones; both axes'
    # crossings are then placed and labelled together.
    # (the arrays' own nonzero: np.flatnonzero's wrapper makes three calls more)
    h_rows, h_cols = np.divmod((above[:, :-1] != above[:, 1:]).ravel().nonzero()[0], width - 1)
    k_v = (above[:-1, :] != above[1:, :]).ravel().nonzero()[0]
    n_h = len(h_rows)
    if n_h + len(k_v) == 0:
        return []
    ka = np.concatenate([h_rows * width + h_cols, k_v])
    kb = ka + width  # the neighbour along the axis
    kb[:n_h] -= width - 1
    yy, xx = np.divmod(ka, width)
    # Gathers by flat index into the raveled (contiguous) ROI arrays: numpy's two-dimensional
    # fancy indexing recomputes the flat index at every gather.
    flat_patch, flat_above, flat_lb = roi_score.ravel(), above.ravel().view(bool), lb.ravel()
    va = flat_patch.take(ka).astype(np.float32)
    vb = flat_patch.take(kb).astype(np.float32)
    f = (level - va) / (vb - va)
    lab_b = flat_lb.take(np.where(flat_above.take(ka), kb, ka))  # the pixel below the level
    # (the offset along each crossing's own axis; exact: x + 0 is x)
    fx = np.zeros_like(f)
    fx[:n_h] = f[:n_h]
    fy = f - fx
    fy[:n_h] = 0
    px, py = xx + fx, yy + fy
    # The score's gradient (toward the pattern) against the direction from the centre: an outer
    # edge has the pattern on its inner side. (Two Sobel values sum exactly in int16.)
    gx = (gxi.ravel().take(ka) + gxi.ravel().take(kb)).astype(np.float32)
    gy = (gyi.ravel().take(ka) + gyi.ravel().take(kb)).astype(np.float32)
    outer_edge = gx * (px - cx) + gy * (py - cy) < 0
    key = lab_b * 2 + outer_edge
    # (numpy's stable sort of 16-bit keys, as few labels give, is a radix sort)
    order = np.argsort(key.astype(np.int16) if n_labels < 16000 else key, kind="stable")
    key = key[order]
    xy = np.empty((len(key), 2))
    np.add(px[order], x0, out=xy[:, 0])
    np.add(py[order], y0, out=xy[:, 1])
    cuts = [0, *((key[1:] != key[:-1]).nonzero()[0] + 1).tolist(), len(key)]
    return [xy[a:b] for a, b in pairwise(cuts) if b - a >= 8]
