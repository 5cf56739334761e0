"""The fetch's parallel gripper and its grasp of the marked box (core.sim.marked_box): where
the end effector grasps the box in the mark's frame, the pre-grasp pose above it, and what the
fingers do when they close (`close_gripper`)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from core.geometry.poses import invert_pose
from core.sim.marked_box import BOX_SIZE

Array = NDArray[np.float64]

# The parallel gripper: its fingers close along the end effector's y axis, from an opening of
# 0.14 m at 0.10 m/s; 15 mm wide (along x), they reach 0.12 m from the flange to the tips.
GRIPPER_OPEN = 0.14
GRIPPER_SPEED = 0.10
_FINGER_HALF_WIDTH = 0.0075
# The end effector's grasp pose in the mark frame: fingertips 5 cm below the mark (mid-box),
# gripper z pointing down; the pre-grasp pose is 0.20 m back along the approach.
T_MARK_GRASP = np.array(
    [[1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, -0.05], [0.0, 0.0, 0.0, 1.0]]
)
PRE_GRASP = 0.20


def pre_grasp_pose(T_mark_grasp: Array = T_MARK_GRASP) -> Array:
    """Return T_mark_ee (4, 4) of the pre-grasp pose: the grasp pose `T_mark_grasp` moved
    PRE_GRASP back along its approach (the end effector's z)."""
    T = T_mark_grasp.copy()
    T[:3, 3] -= PRE_GRASP * T[:3, 2]
    return T


def close_gripper(T_world_ee: Array, T_world_mark: Array) -> tuple[float, str]:
    """Return (opening in metres where the fingers stop, "" or why the grasp does not hold)
    when the gripper, open at GRIPPER_OPEN with its fingertips' centre at T_world_ee, closes
    on the box whose mark is at T_world_mark.

    The fingers close along the end effector's y axis. The box's half extent along it, h, is
    the support of its top square in that direction; its centre lies o off the fingers'
    midline. The open fingers straddle the box when |o| + h < GRIPPER_OPEN / 2 (otherwise a
    finger lands on it); they then close until both touch, pushing the box to the midline, at
    an opening of 2h. The grasp holds when the fingertips are between 1 cm below the top and
    1 cm above the bottom, and the fingers (15 mm wide) overlap the box along x."""
    E = invert_pose(T_world_mark) @ np.asarray(T_world_ee, dtype=np.float64)  # T_mark_ee
    y, x, p = E[:2, 1], E[:2, 0], E[:3, 3]
    hx, hy, height = BOX_SIZE[0] / 2, BOX_SIZE[1] / 2, BOX_SIZE[2]
    h = hx * abs(float(y[0])) + hy * abs(float(y[1]))
    o = float(p[:2] @ y)  # the fingers' midline off the box's axis (x = y = 0, mark frame)
    if abs(o) + h >= GRIPPER_OPEN / 2:
        return GRIPPER_OPEN, "a finger landed on the box (the open gripper does not straddle it)"
    if not -height + 0.01 <= float(p[2]) <= -0.01:
        return 0.0, "the fingertips are not beside the box (too high or too low)"
    along = abs(float(p[:2] @ x))
    if along > hx * abs(float(x[0])) + hy * abs(float(x[1])) + _FINGER_HALF_WIDTH:
        return 0.0, "the fingers closed beside the box, not on it"
    return 2.0 * h, ""
