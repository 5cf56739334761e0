"""The arm models: the twin's arm (`default_arm()`) is the Puma 560's geometry (Corke's
standard-DH model, the same numbers as roboticstoolbox's `models.DH.Puma560` with its shoulder
height d1 moved into the robot's mount), with that model's joint limits and a 0.12 m gripper as
its tool."""

from __future__ import annotations

import numpy as np

from core.manipulation.arm import PUMA_ALPHA, DHArm


def puma_like_arm() -> DHArm:
    """Return the Puma-560-geometry arm of the twin's mobile manipulator.

    Standard DH (Corke, RVC 2nd ed., tab. 7.1): a = (0, 0.4318, 0.0203, 0, 0, 0) m,
    d = (0, 0, 0.15005, 0.4318, 0, 0) m, alpha = (90, 0, -90, 90, -90, 0) deg; the shoulder
    height is the mount's, not d1. Limits (deg): (+-160, -45..225, -225..45, -110..170, +-100,
    +-266), those of roboticstoolbox's Puma560. Tool: a parallel gripper whose fingertip centre
    (the end effector) is 0.12 m along the flange's z axis. Home: (0, 45, -160, 0, 45, 0) deg,
    elbow up with the gripper pointing forward and down.
    """
    deg = np.pi / 180.0
    tool = np.eye(4)
    tool[2, 3] = 0.12
    return DHArm(
        name="puma-like",
        a=np.array([0.0, 0.4318, 0.0203, 0.0, 0.0, 0.0]),
        d=np.array([0.0, 0.0, 0.15005, 0.4318, 0.0, 0.0]),
        alpha=PUMA_ALPHA.copy(),
        offset=np.zeros(6),
        limits=np.array(
            [[-160, 160], [-45, 225], [-225, 45], [-110, 170], [-100, 100], [-266, 266]]
        )
        * deg,
        tool=tool,
        home=np.array([0.0, 45.0, -160.0, 0.0, 45.0, 0.0]) * deg,
    )


def default_arm() -> DHArm:
    """Return the twin's arm (`puma_like_arm()`)."""
    return puma_like_arm()
