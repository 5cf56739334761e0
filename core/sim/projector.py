"""The twin's projector: the installer's model of it and the true unit.

The scene gives the projector's nominal mount (what the installer entered: `nominal_projector`);
the twin's true unit (`twin_projector`) departs from it by a seeded mounting error
(`MOUNT_ERROR_*`) and carries small Denavit-Hartenberg offsets (`TRUE_OFFSETS`), as a real unit
does. Estimators only ever see the nominal model, the commanded angles and the measurements;
the true unit draws the spot and scores.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from core.geometry.poses import pose_from_quaternion
from core.geometry.rotations import rotvec_to_matrix
from core.projector import PanTiltProjector
from core.sim.scene import Scene

Array = NDArray[np.float64]

# The twin's true projector departs from the scene's nominal mount by these (per axis,
# Gaussian standard deviations) and carries these DH offsets.
MOUNT_ERROR_POSITION = 0.03
MOUNT_ERROR_ANGLE = math.radians(1.0)
# A pan zero offset is a turn of the mount about the pan axis (not separable from it), so the
# twin folds it into the mount error.
TRUE_OFFSETS = {"theta": (0.0, -0.008), "d": (0.0, 0.0), "a": (0.0, 0.0)}


def nominal_projector(scene: Scene) -> PanTiltProjector:
    """Return the installer's model of the scene's projector: its nominal mount, ideal joints."""
    p = scene.projector
    if p is None:
        raise InvalidInput(f"scene {scene.name!r} has no projector")
    if p.pose.quaternion_xyzw is None:
        raise InvalidInput("the projector's pose must be given with quaternion_xyzw")
    return PanTiltProjector(
        pose_from_quaternion(p.pose.position, p.pose.quaternion_xyzw),
        pan_limits=p.pan_limits,
        tilt_limits=p.tilt_limits,
        max_rate=(p.max_rate, p.max_rate),
        max_acceleration=(4.0, 4.0),
    )


def twin_projector(scene: Scene, seed: int) -> PanTiltProjector:
    """Return the twin's true projector (for simulation and scoring only)."""
    nominal = nominal_projector(scene)
    rng = np.random.default_rng([seed, 3003])
    dT = np.eye(4)
    dT[:3, :3] = rotvec_to_matrix(rng.normal(0.0, MOUNT_ERROR_ANGLE, 3))
    dT[:3, 3] = rng.normal(0.0, MOUNT_ERROR_POSITION, 3)
    return PanTiltProjector(
        nominal.T_world_base @ dT,
        theta=np.array(TRUE_OFFSETS["theta"]),
        d=np.array(TRUE_OFFSETS["d"]),
        a=np.array(TRUE_OFFSETS["a"]),
        pan_limits=nominal.pan_limits,
        tilt_limits=nominal.tilt_limits,
        max_rate=nominal.max_rate,
        max_acceleration=nominal.max_acceleration,
    )
