"""Where the fetch's base stands and how it gets there: the corridor between the kitchen
counter and the dining table, the placements from which the arm reaches the pre-grasp pose over
the mark and has room for the controller's first look and probe (`place_with_room`), whether a
fetch can start at all (`fetch_problem`), the base's drive there (`drive_poses`) and the arm's
posture while it drives (`look_posture`)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from core.geometry.poses import invert_pose, planar_pose
from core.geometry.rotations import wrap_angle
from core.manipulation import BasePlacement, MobileManipulator
from core.sim.gripper import pre_grasp_pose

Array = NDArray[np.float64]

# The corridor between the kitchen counter and the dining table where the base may stand.
CORRIDOR_Y = (0.95, 1.2)


def drive_poses(
    start: Array, goal: Array, dt: float, v_max: float = 0.5, w_max: float = 1.5
) -> list[Array]:
    """Return the base poses of a unicycle turning to face the goal, driving straight to it and
    turning to its heading, at constant speed limits (velocity limits; accelerations ignored)."""
    poses = [start.copy()]
    x = start.copy()

    def turn_to(heading: float) -> None:
        while True:
            err = wrap_angle(float(heading - x[2]))
            if abs(err) < 1e-9:
                break
            x[2] += float(np.clip(err, -w_max * dt, w_max * dt))
            poses.append(x.copy())

    origin = x[:2].copy()
    d = goal[:2] - origin
    dist = float(np.linalg.norm(d))
    if dist > 1e-6:
        turn_to(math.atan2(d[1], d[0]))
        steps = math.ceil(dist / (v_max * dt))
        for k in range(1, steps + 1):
            x[:2] = origin + d * (k / steps)
            poses.append(x.copy())
    turn_to(float(goal[2]))
    return poses


def base_candidates(T_world_mark: Array) -> Array:
    """Return the base poses (n, 3) a fetch may stand at for a mark: in the corridor between
    the kitchen counter and the dining table, beside the mark, facing the table (+y)."""
    return np.array(
        [
            [T_world_mark[0, 3] + dx, y, math.pi / 2 + dth]
            for dx in np.linspace(-0.3, 0.3, 7)
            for y in np.linspace(*CORRIDOR_Y, 3)
            for dth in (-0.4, -0.2, 0.0, 0.2, 0.4)
        ]
    )


# The first look is taken this far above the pre-grasp view, along the camera's axis (m), and
# the look-then-move probe moves the camera by these (m, camera frame) from there.
LOOK_BACK = 0.05
PROBE_SHIFTS = ((0.03, 0.0, -0.03), (-0.03, 0.0, -0.03), (0.0, 0.03, -0.03), (0.0, -0.03, -0.03))
# The base is placed where the arm also reaches the first look and a probe for the mark moved
# by this along each floor axis (m): the prior's standard deviation (grasp_episode's default).
ROOM_M = 0.05


def has_room(mm: MobileManipulator, T_world_mark: Array, T_ee_cam: Array, base: Array) -> bool:
    """Return whether the arm, from base pose `base` (x, y, theta), reaches the poses the
    controller moves through around the pre-grasp pose over the believed mark
    `T_world_mark`: the first look (LOOK_BACK above the pre-grasp view) and at least one of
    its probe motions (PROBE_SHIFTS), for the mark where it is believed and moved by ROOM_M
    along each floor axis. `T_ee_cam` is the hand-eye estimate."""
    T_arm_world = invert_pose(planar_pose(base) @ mm.T_base_arm)
    probes = []
    for shift in PROBE_SHIFTS:
        P = np.eye(4)
        P[:3, 3] = shift
        probes.append(T_ee_cam @ P @ invert_pose(T_ee_cam))
    for dx, dy in ((0.0, 0.0), (ROOM_M, 0.0), (-ROOM_M, 0.0), (0.0, ROOM_M), (0.0, -ROOM_M)):
        look = T_world_mark @ pre_grasp_pose()
        look[:3, 3] += [dx, dy, 0.0]
        look[:3, 3] -= LOOK_BACK * look[:3, 2]
        T = T_arm_world @ look
        if not mm.arm.ik_analytic(T) or not any(mm.arm.ik_analytic(T @ P) for P in probes):
            return False
    return True


def place_with_room(
    mm: MobileManipulator, T_world_mark: Array, T_ee_cam: Array, start: Array
) -> BasePlacement:
    """Return the base placement (MobileManipulator.place_base over the corridor's
    candidates) for the pre-grasp pose over the believed mark from which the arm also has
    room for the first look and its probe (`has_room`): the best placement, then the next
    best while one lacks that room; the best when none has it. Raises InvalidInput when no
    candidate reaches the pre-grasp pose."""
    target = T_world_mark @ pre_grasp_pose()
    cands = base_candidates(T_world_mark)
    best = place = mm.place_base(target, start, candidates=cands)
    while not has_room(mm, T_world_mark, T_ee_cam, place.base):
        cands = cands[np.any(cands != place.base, axis=1)]
        try:
            place = mm.place_base(target, start, candidates=cands)
        except InvalidInput:
            return best
    return place


# A mark the controller grasps faces up: its normal within this of the world's +Z.
_MAX_MARK_TILT = math.radians(20.0)


def fetch_problem(mm: MobileManipulator, T_world_mark: Array) -> str | None:
    """Return why the fetch of a box whose mark is at `T_world_mark` (4, 4; the semantic map's
    pose) cannot start, or None: the controller grasps a box from above by the mark on its
    top, so the mark must face up (within 20 deg), and a base pose in the kitchen corridor
    must reach its pre-grasp pose within the arm's limits."""
    T = np.asarray(T_world_mark, dtype=np.float64)
    tilt = math.acos(float(np.clip(T[2, 2], -1.0, 1.0)))
    if tilt > _MAX_MARK_TILT:
        return (
            f"its mark faces {math.degrees(tilt):.0f} deg away from up; the grasp controller "
            "takes a box by the mark on its top (within 20 deg of level)"
        )
    cands = base_candidates(T)
    try:
        mm.place_base(T @ pre_grasp_pose(), cands[len(cands) // 2], candidates=cands)
    except InvalidInput:
        x, y, z = (float(v) for v in T[:3, 3])
        return (
            f"no base pose in the kitchen corridor (y {CORRIDOR_Y[0]}-{CORRIDOR_Y[1]} m) "
            f"reaches its pre-grasp pose over ({x:.2f}, {y:.2f}, {z:.2f}) m"
        )
    return None


def look_posture(mm: MobileManipulator) -> Array:
    """Joint values holding the camera 0.45 m above the shoulder, looking ahead and 35 degrees
    down: the posture the approach starts its gaze from."""
    pitch = math.radians(35.0)
    z = np.array([math.cos(pitch), 0.0, -math.sin(pitch)])
    x = np.array([0.0, -1.0, 0.0])
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = [0.30, 0.0, 0.45]
    r = mm.arm.ik(T @ invert_pose(mm.T_ee_camera))
    return r.q
