"""An image as the landmark detector reads it, and its lens maps.

`ImageView` holds the colour image, its grey plane, the camera's calibrated intrinsics, the
world's up (when known) and whether symbols are read; it maps between distorted and ideal
pixels. The edge points' undistortion is Newton's on the lens model started from a grid of
ideal coordinates computed once per camera, so two iterations converge.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from itertools import accumulate
from typing import Any

import numpy as np
from numpy.typing import NDArray

from core.errors import ConvergenceError
from core.geometry.camera import distortion_model, undistort_points

Array = NDArray[np.float64]
Image = NDArray[Any]


@dataclass(frozen=True)
class ImageView:
    """An image being read (BGR, and its grey plane), its camera's intrinsics K (3, 3) and lens
    dist, the world's up in camera coordinates (or None) and whether symbols are read."""

    image: Image
    grey: Image  # the per-pixel maximum of the channels: the blue frame and red rings white
    K: Array
    dist: Array
    up: Array | None
    decode: bool

    @functools.cached_property
    def distorted(self) -> bool:
        """Whether the lens model has any non-zero coefficient."""
        return bool(np.any(self.dist))

    def undistort(self, px: Array) -> Array:
        """Return the ideal pixels (N, 2) of distorted pixels px (N, 2)."""
        if not self.distorted:
            return px
        h, w = self.image.shape[:2]
        grid = _ideal_grid(self.K.tobytes(), self.dist.tobytes(), w, h)
        if grid is None:
            return undistort_points(px, self.K, self.dist, to_pixels=True, tol=1e-10)
        return _undistort_from_grid(px, self.K, self.dist, grid)

    def distort(self, ideal: Array) -> Array:
        """Return the distorted pixels (N, 2) of ideal pixels (N, 2)."""
        if not self.distorted:
            return ideal
        # K^-1 of the ideal pixels (K upper triangular, K[2] = (0, 0, 1)).
        (fx, s, cx), (_, fy, cy), _ = self.K.tolist()
        y = (ideal[:, 1] - cy) / fy
        return self._pixels(*distortion_model((ideal[:, 0] - cx - s * y) / fx, y, self.dist)[:2])

    def project(self, P: Array) -> Array:
        """Return the distorted pixels (N, 2) of camera-frame points P (N, 3) in front of it."""
        x, y = P[:, 0] / P[:, 2], P[:, 1] / P[:, 2]
        if self.distorted:
            x, y, _, _ = distortion_model(x, y, self.dist)
        return self._pixels(x, y)

    def _pixels(self, x: Array, y: Array) -> Array:
        """Return the pixels (N, 2) of normalised (distorted) coordinates x, y (N,)."""
        (fx, s, cx), (_, fy, cy), _ = self.K.tolist()
        out = np.empty((len(x), 2))
        np.add(fx * x + s * y, cx, out=out[:, 0])
        np.add(fy * y, cy, out=out[:, 1])
        return out


# The undistortion of the edge points starts from the ideal coordinates of a grid of pixels
# this far apart, interpolated (bilinear: at most 4e-3 px off over bench_landmarks' image, 6e-3
# px over the head camera's), where Newton from the distorted point takes two more iterations.
_GRID_STEP = 8


@functools.lru_cache(maxsize=8)
def _ideal_grid(K: bytes, dist: bytes, width: int, height: int) -> Array | None:
    """Return the ideal normalised coordinates (2, gh, gw) (x, then y) of the distorted pixels
    (j, i) * _GRID_STEP covering a width x height image (once per camera: a few ms), or None
    where the distortion is not invertible on it."""
    xs = np.arange(0, width + _GRID_STEP, _GRID_STEP, dtype=np.float64)
    ys = np.arange(0, height + _GRID_STEP, _GRID_STEP, dtype=np.float64)
    uv = np.stack(np.meshgrid(xs, ys), -1)
    try:
        ideal = undistort_points(uv, np.frombuffer(K).reshape(3, 3), np.frombuffer(dist))
    except ConvergenceError:
        return None
    return np.ascontiguousarray(np.moveaxis(ideal, -1, 0))


def _bilinear(g: Array, k: NDArray[np.intp], width: int, a: Array, b: Array) -> Array:
    """Return the bilinear interpolation of the raveled grid g (rows of `width`) in the cells
    whose top-left nodes are k, at fractions a (down) and b (across)."""
    g00, g01 = g.take(k), g.take(k + 1)
    top = g00 + b * (g01 - g00)
    g10, g11 = g.take(k + width), g.take(k + width + 1)
    return top + a * (g10 + b * (g11 - g10) - top)


def _undistort_from_grid(px: Array, K: Array, dist: Array, grid: Array) -> Array:
    """Return the ideal pixels (N, 2) of distorted pixels px (N, 2): core.geometry.camera's
    undistort_points (Newton on the same model, stopped at a step of 1e-10), started from the
    grid's bilinear interpolation instead of the distorted point, so two iterations converge.
    Raises ConvergenceError where Newton does not converge."""
    gh, gw = grid.shape[1:]
    u, v = px[:, 0] / _GRID_STEP, px[:, 1] / _GRID_STEP
    # (a point off the image extrapolates from the nearest cell: a start all the same)
    j = np.clip(u.astype(np.intp), 0, gw - 2)
    i = np.clip(v.astype(np.intp), 0, gh - 2)
    b, a = u - j, v - i
    k = i * gw + j
    x, y = (_bilinear(g.ravel(), k, gw, a, b) for g in grid)
    return undistort_points(px, K, dist, to_pixels=True, tol=1e-10, start=(x, y))


def undistort_each(ctx: ImageView, points: list[Array]) -> list[Array | None]:
    """Return the ideal pixels of each candidate's edge points (one undistortion for all; a
    candidate where the distortion is not invertible gets None)."""
    if not points:
        return []
    try:
        ideal = ctx.undistort(np.concatenate(points))
        ends = list(accumulate(len(p) for p in points))
        return [ideal[e - len(p) : e] for p, e in zip(points, ends, strict=True)]
    except ConvergenceError:
        out: list[Array | None] = []
        for p in points:
            try:
                out.append(ctx.undistort(p))
            except ConvergenceError:
                out.append(None)
        return out
