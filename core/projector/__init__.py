"""The ceiling pan-tilt laser projector: kinematics, aiming, Jacobian and path projection.

* `PanTiltProjector`: the Denavit-Hartenberg model on its mount; `spot(q)`, `aim(point,
  q_current)`, `jacobian(q)`, `joint_rates`, `spot_velocity`.
* `project_path(projector, path, spot_speed)`: a floor path -> a time-stamped `JointTrajectory`
  within the joints' rate and acceleration limits; `fillet_path` rounds a poly-line's corners.
* Errors: `BeamAboveHorizon`, `BeamMissesFloor`, `UnreachablePoint`, `SingularConfiguration`.
"""

from core.projector._model import (
    SINGULAR_TILT,
    Beam,
    BeamAboveHorizon,
    BeamMissesFloor,
    PanTiltProjector,
    SingularConfiguration,
    SpotJacobian,
    UnreachablePoint,
)
from core.projector._trajectory import JointTrajectory, fillet_path, project_path

__all__ = [
    "SINGULAR_TILT",
    "Beam",
    "BeamAboveHorizon",
    "BeamMissesFloor",
    "JointTrajectory",
    "PanTiltProjector",
    "SingularConfiguration",
    "SpotJacobian",
    "UnreachablePoint",
    "fillet_path",
    "project_path",
]
