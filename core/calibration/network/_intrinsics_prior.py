"""A camera's own calibration as the prior of its intrinsics in the network's calibration."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from core.calibration.zhang import CameraCalibration
from core.geometry.camera import DISTORTION_NAMES

Array = NDArray[np.float64]

#: The intrinsic parameters a camera's own calibration may supply, in the order used here.
INTRINSIC_PARAMETERS: tuple[str, ...] = ("fx", "fy", "cx", "cy", *DISTORTION_NAMES)


@dataclass(frozen=True)
class IntrinsicsPrior:
    """A camera's own calibration as a prior: K (3, 3) pixels, dist (5,) OpenCV coefficients,
    `names` the estimated parameters among INTRINSIC_PARAMETERS (the others are held at their
    values) and `cov` (p, p) their covariance (pixels^2; unitless for distortion)."""

    K: Array
    dist: Array
    names: tuple[str, ...]
    cov: Array

    @classmethod
    def from_calibration(cls, cal: CameraCalibration) -> IntrinsicsPrior:
        """Return the prior of a Zhang calibration (its estimate and covariance; skew, when it
        was estimated, is held at its value)."""
        names = tuple(n for n in INTRINSIC_PARAMETERS if n in cal.parameter_names)
        idx = [cal.parameter_names.index(n) for n in names]
        return cls(cal.K.copy(), cal.dist.copy(), names, cal.covariance[np.ix_(idx, idx)].copy())

    @property
    def values(self) -> Array:
        """The estimated parameters' values (p,), in the order of `names`."""
        full = np.concatenate([[self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]], self.dist])
        return full[[INTRINSIC_PARAMETERS.index(n) for n in self.names]]
