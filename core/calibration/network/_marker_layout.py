"""Where the robot's markers are and which detection is which: the markers' heights, offsets
and disc radii, the observation columns (column j K + k is marker k at stop j) with the
markers' world points at the robot's poses, and the detections checked into those columns."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.calibration.network._intrinsics_prior import IntrinsicsPrior
from core.calibration.network._odometry import OdometryPrior
from core.errors import InvalidInput

Array = NDArray[np.float64]


@dataclass(frozen=True)
class MarkerLayout:
    """Where each observation column's marker is: the robot carries K markers, and column
    n = j K + k holds marker k at stop j: `stop` (N,) the stop, `offset` (N, 2) and `height`
    (N,) the marker's place on the robot, `radius` (N,) its disc's radius, `first` (N,) the
    columns of marker 0 (one height: what a camera's plane pose starts from)."""

    stop: NDArray[np.intp]
    offset: Array
    height: Array
    radius: Array
    first: NDArray[np.bool_]
    markers: int

    @classmethod
    def of(cls, stops: int, offsets: Array, heights: Array, radii: Array) -> MarkerLayout:
        k = len(heights)
        return cls(
            stop=np.repeat(np.arange(stops), k),
            offset=np.tile(offsets, (stops, 1)),
            height=np.tile(heights, stops),
            radius=np.tile(radii, stops),
            first=np.tile(np.arange(k) == 0, stops),
            markers=k,
        )

    def head(self, stops: int) -> MarkerLayout:
        """The layout of the first `stops` stops."""
        n = stops * self.markers
        return MarkerLayout(
            self.stop[:n],
            self.offset[:n],
            self.height[:n],
            self.radius[:n],
            self.first[:n],
            self.markers,
        )

    def points(self, poses: Array) -> tuple[Array, Array]:
        """Return the markers' world points (N, 3) at the robot poses (M, 3) and d X / d pose
        of their stops (N, 3, 3)."""
        P = poses[self.stop]
        c, s = np.cos(P[:, 2]), np.sin(P[:, 2])
        o = self.offset
        ro = np.stack([c * o[:, 0] - s * o[:, 1], s * o[:, 0] + c * o[:, 1]], 1)
        X = np.column_stack([P[:, :2] + ro, self.height])
        dX = np.zeros((len(P), 3, 3))
        dX[:, 0, 0] = dX[:, 1, 1] = 1.0
        dX[:, 0, 2] = -ro[:, 1]
        dX[:, 1, 2] = ro[:, 0]
        return X, dX


def marker_places(
    height: ArrayLike, offset: ArrayLike, radius: ArrayLike
) -> tuple[Array, Array, Array]:
    """Return the K markers' heights (K,), offsets (K, 2) and radii (K,) from one value each
    or one per marker; InvalidInput when they disagree or are not finite."""
    try:
        h = np.atleast_1d(np.asarray(height, dtype=np.float64)).reshape(-1)
        o = np.asarray(offset, dtype=np.float64)
        r = np.atleast_1d(np.asarray(radius, dtype=np.float64)).reshape(-1)
    except (TypeError, ValueError):
        raise InvalidInput("marker heights, offsets and radii must be numbers (metres)") from None
    k = len(h)
    if k == 0 or o.size != 2 * k or len(r) not in (1, k):
        raise InvalidInput(
            f"need one (x, y) offset per marker height and one radius or one per marker: "
            f"{k} heights, offsets {o.shape}, {len(r)} radii"
        )
    o = o.reshape(k, 2)
    r = np.broadcast_to(r, (k,)).copy()
    if not (np.all(np.isfinite(h)) and np.all(np.isfinite(o)) and np.all(np.isfinite(r))):
        raise InvalidInput("marker heights, offsets and radii must be finite")
    if np.any(r < 0):
        raise InvalidInput("marker radii must be >= 0 metres")
    return h, o, r


def check_detections(
    names: Sequence[str],
    intrinsics: Sequence[IntrinsicsPrior],
    pixels: ArrayLike,
    visible: ArrayLike,
    odometry: OdometryPrior,
    pixel_cov: ArrayLike | None,
    pixel_sigma: float,
    markers: int = 1,
) -> tuple[Array, NDArray[np.bool_], Array]:
    """Return pixels (C, N, 2), visibility (C, N) and covariances (C, N, 2, 2) with N = M K
    columns, column j K + k marker k at stop j (`MarkerLayout`), from pixels (C, M, 2) and visible
    (C, M) for one marker or (C, M, K, 2) and (C, M, K) for K."""
    C, K = len(names), markers
    M = len(odometry.increments)
    N = M * K
    try:
        uv = np.asarray(pixels, dtype=np.float64)
        vis = np.asarray(visible, dtype=bool)
    except (TypeError, ValueError):
        raise InvalidInput("pixels must be numbers and visible booleans") from None
    if K == 1 and uv.shape == (C, M, 2):
        uv = uv.reshape(C, M, 1, 2)
    if K == 1 and vis.shape == (C, M):
        vis = vis.reshape(C, M, 1)
    if len(intrinsics) != C or uv.shape != (C, M, K, 2) or vis.shape != (C, M, K):
        shape = "(C, M, 2) and (C, M)" if K == 1 else f"(C, M, {K}, 2) and (C, M, {K})"
        raise InvalidInput(
            f"need one intrinsics prior per camera, pixels and visible {shape} for C = {C} "
            f"names, M = {M} odometry stops and {K} marker(s); got {len(intrinsics)} priors, "
            f"{uv.shape}, {vis.shape}"
        )
    uv = uv.reshape(C, N, 2)
    vis = vis.reshape(C, N)
    if not np.all(np.isfinite(uv[vis])):
        raise InvalidInput("the visible pixels must be finite")
    if pixel_cov is None:
        if not pixel_sigma > 0:
            raise InvalidInput(f"pixel_sigma must be > 0 pixels, got {pixel_sigma}")
        cov = np.broadcast_to(pixel_sigma**2 * np.eye(2), (C, N, 2, 2)).copy()
    else:
        try:
            cov = np.asarray(pixel_cov, dtype=np.float64).reshape(C, N, 2, 2).copy()
        except (TypeError, ValueError):
            raise InvalidInput(f"pixel_cov must be 2 x 2 px^2 per pixel, {C * N} of them") from None
        cov[~vis] = np.eye(2)
        if not np.all(np.isfinite(cov)) or np.any(np.linalg.eigvalsh(cov)[..., 0] <= 0):
            raise InvalidInput("pixel_cov must be positive definite where visible")
    return uv, vis, cov
