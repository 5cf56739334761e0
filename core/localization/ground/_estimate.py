"""What a ground estimator returns: a `FloorEstimate` per call, a `PointStatus` per target."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from typing import Literal

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
Method = Literal["monocular", "linear", "constrained", "ml"]


class PointStatus(IntEnum):
    """Why a target of a batch was (not) located; `OK` is 0, so `status == 0` is `valid`."""

    OK = 0
    TOO_FEW_CAMERAS = 1
    DEGENERATE = 2
    BEHIND_CAMERA = 3


@dataclass(frozen=True)
class FloorEstimate:
    """Floor positions of one target or a batch, with covariances and diagnostics.

    Shapes for a batch of B targets (without the batch axis, drop the leading B):
    `point` (B, 3) world coordinates, metres (Z = `height` for the plane estimators, the
    triangulated Z for `linear`); `point_cov` (B, 3, 3) m^2 (zero Z row and column when Z = h is
    imposed); `status` (B,) `PointStatus` codes; `n_cameras` (B,) cameras used; `rms` (B,) the
    root-mean-square reprojection error in pixels over the used detections. Invalid targets hold
    NaN in `point`, `point_cov` and `rms`.
    """

    method: Method
    height: float | None
    point: Array
    point_cov: Array = field(repr=False)
    status: NDArray[np.int8] = field(repr=False)
    n_cameras: NDArray[np.int64] = field(repr=False)
    rms: Array = field(repr=False)
    iterations: int = 0

    @property
    def xy(self) -> Array:
        """Floor position (..., 2), metres: the world (X, Y) of the estimate."""
        return self.point[..., :2]

    @property
    def cov(self) -> Array:
        """Covariance of the floor position (..., 2, 2), m^2."""
        return self.point_cov[..., :2, :2]

    @property
    def std(self) -> Array:
        """Standard deviations of (X, Y) (..., 2), metres."""
        return np.sqrt(np.diagonal(self.cov, axis1=-2, axis2=-1))

    @property
    def position_std(self) -> Array:
        """Root of the trace of the floor covariance (...), metres: the RMS position error."""
        return np.sqrt(np.trace(self.cov, axis1=-2, axis2=-1))

    @property
    def valid(self) -> NDArray[np.bool_]:
        """Whether each target was located (...)."""
        return self.status == PointStatus.OK
