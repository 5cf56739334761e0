"""Calibrating a camera network by driving the robot with a target over the floor (02 §1).

Two target kinds:

* `calibrate_network_marker`: a marker on the robot, one image point per stop; each camera's
  intrinsics and distortion from its own calibration (`IntrinsicsPrior`), the robot's poses
  from its odometry (`odometry_prior`), all refined jointly; `marker_network_bound` gives the
  Cramer-Rao bound of that calibration.
* `calibrate_network_board`: a chessboard mounted on the robot; each camera gets a full Zhang
  calibration chained into the world by the robot's poses.

Both return a `NetworkCalibration` of `CalibratedCamera`s and `RejectedCamera`s;
`register_planar` and `registered` move one into the world by points known in both frames
(the robot where it read a signpost), freeing it from the start pose's heading.
"""

from core.calibration.network._board import calibrate_network_board
from core.calibration.network._intrinsics_prior import INTRINSIC_PARAMETERS, IntrinsicsPrior
from core.calibration.network._marker import calibrate_network_marker
from core.calibration.network._marker_bound import (
    CameraBound,
    centre_rotation_jacobian,
    floor_gauge_projector,
    marker_network_bound,
)
from core.calibration.network._odometry import (
    OdometryPrior,
    SlipModel,
    compose_increments,
    increment_jacobian,
    odometry_prior,
)
from core.calibration.network._records import CalibratedCamera, NetworkCalibration, RejectedCamera
from core.calibration.network._register import PlanarRegistration, register_planar, registered

__all__ = [
    "INTRINSIC_PARAMETERS",
    "CalibratedCamera",
    "CameraBound",
    "IntrinsicsPrior",
    "NetworkCalibration",
    "OdometryPrior",
    "PlanarRegistration",
    "RejectedCamera",
    "SlipModel",
    "calibrate_network_board",
    "calibrate_network_marker",
    "centre_rotation_jacobian",
    "compose_increments",
    "floor_gauge_projector",
    "increment_jacobian",
    "marker_network_bound",
    "odometry_prior",
    "register_planar",
    "registered",
]
