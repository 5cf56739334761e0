"""Maximum-likelihood floor positions of groups of single detections: each detection is one
camera's view of one group (a labelled target at one time and height), each group located on
its own plane Z = height from the cameras that saw it (`locate_ml`, H&Z sec. 12.3 on the
plane). At most one detection per camera and group."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import InvalidInput
from core.localization.cameras import NetworkCamera
from core.localization.ground import locate_ml

Array = NDArray[np.float64]


class DuplicateView(InvalidInput):
    """One camera detected one group more than once; `index` is the first detection of that
    camera and group."""

    def __init__(self, index: int) -> None:
        super().__init__(f"detection {index} repeats its camera's view of its group")
        self.index = index


@dataclass(frozen=True)
class GroupPositions:
    """Floor positions of B groups: `xy` (B, 2) metres and `cov` (B, 2, 2) m^2 (NaN where not
    located), `status` (B,) `PointStatus` codes, `n_cameras` (B,) cameras used."""

    xy: Array
    cov: Array = field(repr=False)
    status: NDArray[np.int8] = field(repr=False)
    n_cameras: NDArray[np.int64] = field(repr=False)


def locate_groups(
    cameras: Sequence[NetworkCamera],
    camera: ArrayLike,
    group: ArrayLike,
    heights: ArrayLike,
    pixels: ArrayLike,
    pixel_cov: ArrayLike,
) -> GroupPositions:
    """Return the ML floor position of each group of detections.

    cameras: the C cameras. For N detections: `camera` (N,) index into `cameras`, `group` (N,)
    index of the group in [0, B), `pixels` (N, 2) distorted pixels, `pixel_cov` (N, 2, 2) px^2.
    `heights` (B,): each group's height (m) above the floor. Groups of one height are located
    in one batch of `locate_ml`. Raises DuplicateView when a camera saw a group twice.
    """
    cam = np.asarray(camera, dtype=np.intp).reshape(-1)
    grp = np.asarray(group, dtype=np.intp).reshape(-1)
    heights = np.asarray(heights, dtype=np.float64).reshape(-1)
    n, C, B = cam.size, len(cameras), heights.size
    pix = np.asarray(pixels, dtype=np.float64).reshape(n, 2)
    cov = np.asarray(pixel_cov, dtype=np.float64).reshape(n, 2, 2)
    if grp.size != n:
        raise InvalidInput(f"camera and group must have one index per detection: {n} != {grp.size}")
    if n and (cam.min() < 0 or cam.max() >= C or grp.min() < 0 or grp.max() >= B):
        raise InvalidInput(f"camera indices must lie in [0, {C}) and group indices in [0, {B})")
    pair = cam * B + grp
    _, first, counts = np.unique(pair, return_index=True, return_counts=True)
    if np.any(counts > 1):
        raise DuplicateView(int(first[np.argmax(counts > 1)]))
    xy = np.full((B, 2), np.nan)
    xy_cov = np.full((B, 2, 2), np.nan)
    status = np.zeros(B, dtype=np.int8)
    n_cam = np.zeros(B, dtype=np.int64)
    for h in np.unique(heights):
        sel = np.flatnonzero(heights == h)
        remap = np.full(B, -1)
        remap[sel] = np.arange(sel.size)
        mine = remap[grp] >= 0
        view = np.zeros((C, sel.size, 2))
        view_cov = np.tile(np.eye(2), (C, sel.size, 1, 1))
        visible = np.zeros((C, sel.size), dtype=bool)
        idx = (cam[mine], remap[grp[mine]])
        view[idx], view_cov[idx], visible[idx] = pix[mine], cov[mine], True
        est = locate_ml(cameras, view, float(h), visible=visible, pixel_cov=view_cov)
        xy[sel], xy_cov[sel] = est.xy, est.cov
        status[sel], n_cam[sel] = est.status, est.n_cameras
    return GroupPositions(xy, xy_cov, status, n_cam)
