"""Errors of a network calibration against the twin's true cameras (scoring only).

`calibration_errors`: one calibrated camera's focal length, position and orientation against
the true camera; `aligned_errors`: the same after removing the floor rigid motion that best
aligns the calibrated centres to the true ones (the error of the network's own geometry).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from core.calibration.network import (
    CalibratedCamera,
    floor_gauge_projector,
)
from core.geometry.rotations import matrix_to_rotvec
from core.sim.render import CameraModel

Array = NDArray[np.float64]


@dataclass(frozen=True)
class PoseErrors:
    """Errors of a calibrated camera against the twin's true camera: focal length (% of the
    true mean focal length, signed), position (m) and orientation (degrees)."""

    focal_pct: float
    position_m: float
    rotation_deg: float


def calibration_errors(cal: CalibratedCamera, true: CameraModel) -> PoseErrors:
    """Return the errors of `cal` against the scene's camera `true` (scoring)."""
    f_true = 0.5 * (true.K[0, 0] + true.K[1, 1])
    rot = matrix_to_rotvec(cal.R @ true.R_camera_world.T)
    return PoseErrors(
        focal_pct=float(100 * (cal.focal - f_true) / f_true),
        position_m=float(np.linalg.norm(cal.position - true.position)),
        rotation_deg=float(np.degrees(np.linalg.norm(rot))),
    )


def aligned_errors(
    cals: list[CalibratedCamera], trues: list[CameraModel]
) -> list[tuple[float, float]]:
    """Return each camera's (position m, orientation degrees) error after removing the floor
    rigid motion (x, y, yaw) that best aligns the calibrated centres to the true ones
    (core.calibration.network.floor_gauge_projector, first order): the error of the network's
    own geometry. NaN with fewer than 2 cameras (scoring)."""
    if len(cals) < 2:
        return [(float("nan"), float("nan"))] * len(cals)
    e = np.zeros(6 * len(cals))
    for k, (cal, true) in enumerate(zip(cals, trues, strict=True)):
        e[6 * k : 6 * k + 3] = cal.position - true.position
        e[6 * k + 3 : 6 * k + 6] = matrix_to_rotvec(cal.R.T @ true.R_camera_world)
    a = floor_gauge_projector([t.position for t in trues]) @ e
    return [
        (
            float(np.linalg.norm(a[6 * k : 6 * k + 3])),
            float(np.degrees(np.linalg.norm(a[6 * k + 3 : 6 * k + 6]))),
        )
        for k in range(len(cals))
    ]
