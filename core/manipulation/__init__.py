"""Mobile manipulation: the arm and the whole chain's kinematics, inverse kinematics,
hand-eye calibration.

* `default_arm()`: the twin's 6-joint Puma-type arm (`DHArm`): `fk`, `jacobian`,
  `ik_analytic` (every closed-form branch within limits), `ik` (numerical, `IKResult`).
* `default_manipulator()`: the arm on the differential-drive base with its eye-in-hand camera
  (`MobileManipulator`): whole-chain `fk`, `jacobian`, `ik` with a redundancy objective,
  `place_base`.
* `calibrate_hand_eye(T_base_ee, T_cam_target, method=...)`: X = T_ee_cam by Tsai-Lenz,
  Park-Martin, Daniilidis or the two-group linear method, refined by reprojection error.
* The switching grasp controller's core (core.manipulation.grasp): `gaze_step`, `ModeSwitch`,
  `first_look` / `next_look` (look then move from a taught image of a planar mark).
"""

from core.geometry.poses import invert_pose, pose_error
from core.manipulation.arm import DHArm
from core.manipulation.arm_models import default_arm, puma_like_arm
from core.manipulation.chain import (
    BasePlacement,
    MobileManipulator,
    default_manipulator,
)
from core.manipulation.errors import DegenerateMotions, TooFewMotions, Unreachable
from core.manipulation.grasp import ModeSwitch, PlaneEstimate, first_look, gaze_step, next_look
from core.manipulation.hand_eye import METHODS, HandEyeCalibration, calibrate_hand_eye
from core.manipulation.numerical_ik import IKResult

__all__ = [
    "METHODS",
    "BasePlacement",
    "DHArm",
    "DegenerateMotions",
    "HandEyeCalibration",
    "IKResult",
    "MobileManipulator",
    "ModeSwitch",
    "PlaneEstimate",
    "TooFewMotions",
    "Unreachable",
    "calibrate_hand_eye",
    "default_arm",
    "default_manipulator",
    "first_look",
    "gaze_step",
    "invert_pose",
    "next_look",
    "pose_error",
    "puma_like_arm",
]
