"""The fetch on the twin: the arm's switching grasp controller (core.manipulation.grasp) fetching
the marked box (core.sim.marked_box) with its eye-in-hand camera (core.sim.eye_in_hand).

* `prepare_fetch(...)`: what a fetch needs before its first episode, in this order on one
  generator: the eye-in-hand camera's intrinsics (its own calibration), its hand-eye transform
  (calibrated from 15 views and refined, unless the arm already has one applied), and the mark
  taught once (`taught_image`).
* `fetch_episodes(...)`: the episodes (`grasp_episode`) that follow on the same generator.
* `grasp_episode(...)`: one fetch of the box on the dining table: every image the controller
  uses (the gaze while driving, each look, the taught image) is rendered by the twin and the
  mark's corners detected in it, plus pixel noise; the parallel gripper opens, and closes on
  the box where the controller put it (`close_gripper`).

What it builds on, one module each: the gripper and its grasp pose over the mark
(core.sim.gripper), where the base stands and how it drives there (core.sim.fetch_placement),
the eye-in-hand camera's view of the mark and the taught image (core.sim.mark_eye).

The `grasp` scenario (core.sim.scenarios.manipulation) and the service's fetch task
(server.services.manipulation.run_fetch) both run it through these, so a task's episodes with
the twin's arm are the scenario's.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import partial

import numpy as np
from numpy.typing import NDArray

from core.calibration import estimate_plane_pose
from core.errors import InvalidInput
from core.geometry.poses import invert_pose, planar_pose
from core.geometry.rotations import nearest_rotation
from core.manipulation import MobileManipulator, calibrate_hand_eye, pose_error
from core.manipulation.grasp import ModeSwitch, first_look, gaze_step, next_look
from core.sim.eye_in_hand import eye_camera_intrinsics, hand_eye_views
from core.sim.fetch_placement import (
    CORRIDOR_Y,
    LOOK_BACK,
    PROBE_SHIFTS,
    drive_poses,
    look_posture,
    place_with_room,
)
from core.sim.gripper import (
    GRIPPER_OPEN,
    GRIPPER_SPEED,
    PRE_GRASP,
    T_MARK_GRASP,
    close_gripper,
    pre_grasp_pose,
)
from core.sim.intrinsics import RenderedCalibration
from core.sim.mark_eye import MarkEye, mark_on_table, taught_image
from core.sim.marked_box import MARK_POINTS
from core.sim.render import Renderer

Array = NDArray[np.float64]

# The phases of a fetch (grasp_episode's on_phase), in order.
GRASP_PHASES = ("approach", "switch", "look then move", "grasp", "lift and carry")
# The arm's joint position control: every joint at most this fast (rad/s), and a pause for
# the arm to settle before the camera takes its image.
JOINT_RATE = 1.0
SETTLE_S = 0.2
# What the fetch grasps, as its record says it (spec 05 grasps the object its object mark, spec
# 04's blue frame, identifies; this controller servoes on a chessboard printed on the box).
GRASP_TARGET = (
    "a box (160 x 115 x 100 mm) whose top carries a printed 6 x 5 chessboard, not spec 04's "
    "object mark: the controller servoes on the chessboard's 30 corners (find_chessboard); the "
    "box stands where the semantic map's object is (or at random on the dining table), off by "
    "the map's error"
)


@dataclass(frozen=True)
class GraspEpisode:
    """One fetch: success, final end-effector error at the grasp (mm, deg) against the true
    grasp pose, simulated time (s), the mark's visibility during the approach (fraction of
    steps), mode switches, looks made, the failure reason (empty on success), the phase
    (GRASP_PHASES) it ended in (the failed one, or the last on success), the gripper's opening
    where its fingers stopped when it closed (mm; NaN if it never closed) and the eye-in-hand
    images the episode took."""

    success: bool
    position_error_mm: float
    rotation_error_deg: float
    time_s: float
    visible_fraction: float
    switches: int
    looks: int
    reason: str
    phase: str
    gripper_opening_mm: float = math.nan
    frames: int = 0


def grasp_episode(
    rng: np.random.Generator,
    mm: MobileManipulator,
    X_est: Array,
    *,
    intrinsics: RenderedCalibration,
    sigma_px: float = 0.5,
    prior_sigma_m: float = 0.05,
    prior_sigma_rad: float = 0.15,
    dt: float = 0.1,
    max_looks: int = 6,
    on_phase: Callable[[str], None] | None = None,
    T_world_prior: Array | None = None,
    on_joints: Callable[[Array], None] | None = None,
    renderer: Renderer | None = None,
    taught: Array | None = None,
    on_gripper: Callable[[float], None] | None = None,
    on_box: Callable[[Array], None] | None = None,
) -> GraspEpisode:
    """Run one randomised fetch and return its metrics (see `grasp`).

    `T_world_prior` (4, 4), when given, is the mark's pose as the semantic map holds it: the
    episode fetches the box there, and the twin puts its true box off that pose by the prior's
    errors (N(0, prior_sigma_m^2) per floor axis, N(0, prior_sigma_rad^2) in yaw; the map's
    height kept). Without it the box is placed at random on the dining table and the prior
    drawn around it. `on_joints(q)`, when given, is called with the arm's joint values (6,)
    each time the arm moves: every control step of the approach, each look, the grasp, the
    lift. `on_gripper(opening)` likewise with the gripper's opening (m) when it opens at the
    start and where it stops when it closes. `on_box(T_arm_box)` likewise with the twin's box
    in the arm's base frame (4, 4; the mark frame: the top's centre, z up out of the box):
    where the robot starts, at each step of the approach's gaze (the base drives), and once
    the gripper holds it, as it closes (the fingers push the box onto their midline) and at
    each step of the lift; a step's box comes before its joints.

    `renderer`, when given, renders every eye-in-hand image the controller uses (the mark's
    corners are detected in them); without it the controller sees the corners' true
    projections. Both add N(0, sigma_px^2). Every estimate from those pixels uses the camera's
    calibrated `intrinsics` (eye_camera_intrinsics). `taught`: the mark's taught ideal pixels
    (M, 2) (`taught_image`), made from the true hand-eye transform when not given.

    `on_phase(name)`, when given, is called as the episode enters each of GRASP_PHASES, in
    order: "approach" (base placement, driving with the gaze constraint, the first look over
    the believed mark), "switch" (the hysteresis switch to look-then-move on the mark's
    distance and image size), "look then move" (the probe motion, the first look's plane and
    the iterated looks), "grasp" (descend and close), "lift and carry". An episode that fails
    on the way enters no later phase, and its `phase` names the one it failed in; a grasp off
    by more than 5 mm / 2 deg is only found by scoring against the twin after the carry, and
    is attributed to "grasp".
    """
    phase = GRASP_PHASES[0]

    def enter(name: str) -> None:
        nonlocal phase
        phase = name
        if on_phase is not None:
            on_phase(name)

    K, dist = intrinsics.K, intrinsics.dist
    enter("approach")
    if T_world_prior is None:
        xy = np.array([rng.uniform(5.95, 6.65), rng.uniform(1.60, 1.72)])
        T_mark = mark_on_table(xy, rng.uniform(-math.pi, math.pi))
        # The prior: the mark's pose as the semantic map holds it.
        yaw_err = float(rng.normal(0.0, prior_sigma_rad))
        T_prior = mark_on_table(xy + rng.normal(0.0, prior_sigma_m, 2), 0.0)
        T_prior[:3, :3] = T_mark[:3, :3] @ mark_on_table(np.zeros(2), yaw_err)[:3, :3]
    else:
        T_prior = np.array(T_world_prior, dtype=np.float64)
        # The twin's box, where the map is wrong by the prior's errors.
        yaw_err = float(rng.normal(0.0, prior_sigma_rad))
        T_mark = mark_on_table(T_prior[:2, 3] + rng.normal(0.0, prior_sigma_m, 2), 0.0)
        T_mark[:3, :3] = T_prior[:3, :3] @ mark_on_table(np.zeros(2), yaw_err)[:3, :3]
        T_mark[2, 3] = T_prior[2, 3]
    eye = MarkEye(T_mark, sigma_px, rng, renderer)
    if on_gripper is not None:
        on_gripper(GRIPPER_OPEN)
    start = np.array([rng.uniform(5.0, 7.4), rng.uniform(*CORRIDOR_Y), rng.uniform(-3.1, 3.1)])
    # The robot's own estimate of its start pose (its localisation), 3 cm / 0.03 rad off; it
    # then knows its motion by odometry (exact here: the drive has no wheel slip).
    start_est = start + np.array([*rng.normal(0.0, 0.03, 2), rng.normal(0.0, 0.03)])
    T_ee_cam = X_est
    t = 0.0
    held: Array | None = None  # T_ee_box once the gripper holds the box

    def show_box(T_world_arm_true: Array) -> None:
        if on_box is not None:
            on_box(invert_pose(T_world_arm_true) @ T_mark)

    show_box(planar_pose(start) @ mm.T_base_arm)

    def fail(reason: str, vis: float, sw: int, looks: int) -> GraspEpisode:
        return GraspEpisode(
            False, math.nan, math.nan, t, vis, sw, looks, reason, phase, frames=eye.frames
        )

    # Base placement for the prior's pre-grasp pose, from the corridor.
    try:
        # Where the arm has room for the first look and its probe, not only the pre-grasp
        # pose: the nearest base that barely reaches the pre-grasp pose left the arm no
        # room to move the camera up and sideways from there (seed 102's reach failures).
        place = place_with_room(mm, T_prior, T_ee_cam, start_est)
    except InvalidInput:
        return fail("no base placement", 0.0, 0, 0)
    q = look_posture(mm)
    if on_joints is not None:
        on_joints(q)
    switch = ModeSwitch()
    seen = steps = 0
    mark_est = T_prior[:3, 3].copy()  # the mark's position as the robot believes it
    # The commanded path in the robot's belief, and the same motion from its true start.
    offset = planar_pose(start) @ invert_pose(planar_pose(start_est))

    def gaze_once(base_est: Array) -> None:
        nonlocal q, mark_est, seen, steps
        T_base_est = planar_pose(base_est)
        show_box(offset @ T_base_est @ mm.T_base_arm)
        F_est = T_base_est @ mm.T_base_arm @ mm.arm.fk(q) @ T_ee_cam
        px = eye.observe(offset @ T_base_est @ mm.T_base_arm @ mm.arm.fk(q) @ mm.T_ee_camera)
        steps += 1
        if px is None:
            # Not in view: aim at where the mark is believed to be (the gaze constraint keeps
            # it in view once seen; before, it brings it into view).
            ray = invert_pose(F_est)[:3, :3] @ mark_est + invert_pose(F_est)[:3, 3]
            if ray[2] <= 0.05:
                ray = np.array([0.0, 0.0, 1.0])
        else:
            seen += 1
            ray = np.append((px.mean(axis=0) - K[:2, 2]) / np.diag(K)[:2], 1.0)
            pose = estimate_plane_pose(MARK_POINTS, px, K, dist)
            mark_est = F_est[:3, :3] @ pose.t + F_est[:3, 3]
            size = float(np.linalg.norm(px[0] - px[-1]))
            switch.update(float(np.linalg.norm(pose.t)), size)
        # Joint position control with rate limits: JOINT_RATE per joint.
        step = gaze_step(mm.arm, q, T_ee_cam, ray)
        lim = JOINT_RATE * dt
        q = np.clip(q + np.clip(step, -lim, lim), mm.arm.limits[:, 0], mm.arm.limits[:, 1])
        if on_joints is not None:
            on_joints(q)

    for base_est in drive_poses(start_est, place.base, dt):
        t += dt
        gaze_once(base_est)
    # Arrived: keep looking (base still) for up to 3 s until the switch fires.
    for _ in range(30):
        if switch.mode == "look":
            break
        t += dt
        gaze_once(place.base)
    # From here on the base stands still: the arm works in its own frame; the true frame is
    # used only to render what the camera sees and to score.
    T_world_arm = offset @ planar_pose(place.base) @ mm.T_base_arm
    T_arm_world_est = invert_pose(planar_pose(place.base) @ mm.T_base_arm)
    T_arm_mark_prior = T_arm_world_est @ T_prior
    # The look pose is placed over the mark as last seen (its position), oriented by the prior.
    T_arm_mark_prior[:3, 3] = T_arm_world_est[:3, :] @ np.append(mark_est, 1.0)

    def move_to(T_arm_ee: Array, q0: Array) -> Array | None:
        """Solve the IK for T_arm_ee from q0 and, when it succeeds, move there: joint position
        control at JOINT_RATE (the joints move together, the slowest sets the time), each
        control step's joints reported; then the arm settles (SETTLE_S)."""
        nonlocal t
        r = mm.arm.ik(T_arm_ee, q0=q0)
        if not r.success:
            return None
        steps = max(1, math.ceil(float(np.max(np.abs(r.q - q0))) / (JOINT_RATE * dt)))
        for k in range(1, steps + 1):
            qk = q0 + (r.q - q0) * (k / steps)
            if on_box is not None and held is not None:
                on_box(mm.arm.fk(qk) @ held)
            if on_joints is not None:
                on_joints(qk)
        t += steps * dt + SETTLE_S
        return r.q

    # The approach ends with the camera brought over the believed mark: the first look, from
    # 5 cm above the pre-grasp pose. If the mark is not in view there (a belief off by the
    # prior's and the localisation's errors, never corrected by a sighting), the camera
    # searches around it (8 cm steps in its image plane), re-locates the mark by its pose
    # estimate when it appears, and comes back over it.
    vis = seen / max(steps, 1)

    def look_from(
        T_arm_mark: Array, dx: float, dy: float, q_from: Array
    ) -> tuple[Array | None, Array, Array | None]:
        """Camera 5 cm above the pre-grasp view (or at it, if out of reach), shifted by
        (dx, dy) in its image plane: (joints or None, camera pose, pixels or None)."""
        for back in (LOOK_BACK, 0.0):
            look = T_arm_mark @ pre_grasp_pose()
            look[:3, 3] -= back * look[:3, 2]
            shift = np.eye(4)
            shift[:3, 3] = [dx, dy, 0.0]
            qk = move_to(look @ T_ee_cam @ shift @ invert_pose(T_ee_cam), q_from)
            if qk is not None:
                F = mm.arm.fk(qk) @ T_ee_cam
                return qk, F, eye.observe(T_world_arm @ F)
        return None, np.eye(4), None

    search = [(0.0, 0.0)] + [
        (dx, dy) for dx in (-0.08, 0.0, 0.08) for dy in (-0.08, 0.0, 0.08) if dx or dy
    ]
    q1: Array | None = None
    px1: Array | None = None
    F1 = np.eye(4)
    for dx, dy in search:
        qk, Fk, pk = look_from(T_arm_mark_prior, dx, dy, q if q1 is None else q1)
        if qk is None:
            continue
        q1, F1, px1 = qk, Fk, pk
        if px1 is None or (dx == 0.0 and dy == 0.0):
            if px1 is not None:
                break
            continue
        # Seen from a search pose: re-locate the mark and look again from over it.
        est = estimate_plane_pose(MARK_POINTS, px1, K, dist)
        T_arm_mark_prior[:3, 3] = F1[:3, :3] @ est.t + F1[:3, 3]
        qk, Fk, pk = look_from(T_arm_mark_prior, 0.0, 0.0, q1)
        if qk is not None:
            q1, F1, px1 = qk, Fk, pk
        else:
            px1 = None
        break
    if q1 is None:
        return fail("look pose unreachable", vis, switch.switches, 0)
    if px1 is None:
        return fail("mark not in view at the first look", vis, switch.switches, 1)
    enter("switch")
    pose1 = estimate_plane_pose(MARK_POINTS, px1, K, dist)
    if switch.update(float(np.linalg.norm(pose1.t)), float(np.linalg.norm(px1[0] - px1[-1]))) != (
        "look"
    ):
        return fail("mark never near and large enough to switch", vis, switch.switches, 1)
    enter("look then move")
    # One small known camera motion (the first of these the arm reaches).
    q2 = None
    for shift in PROBE_SHIFTS:
        probe = np.eye(4)
        probe[:3, 3] = shift
        q2 = move_to(F1 @ probe @ invert_pose(T_ee_cam), q1)
        if q2 is not None:
            break
    if q2 is None:
        return fail("probe motion unreachable", vis, switch.switches, 1)
    F2 = mm.arm.fk(q2) @ T_ee_cam
    px2 = eye.observe(T_world_arm @ F2)
    if px2 is None:
        return fail("mark not in view after the probe motion", vis, switch.switches, 1)
    # The taught image: the mark's ideal pixels from the pre-grasp pose, recorded once.
    if taught is None:
        taught = taught_image(
            mm.T_ee_camera, intrinsics, renderer=renderer, rng=rng, sigma_px=sigma_px
        )
    try:
        plane = first_look(F1, px1, F2, px2, taught, K, dist)
    except (InvalidInput, ValueError) as exc:
        return fail(f"first look failed: {exc}", vis, switch.switches, 2)
    target_cam = plane.taught_camera
    qc = q2
    looks = 2
    # Each look re-estimates the same fixed taught pose; their mean (rotation: the nearest
    # rotation to the mean matrix) averages the pixel noise down. Stop when a new look moves
    # the mean by less than 0.2 mm and 0.02 degrees.
    estimates: list[Array] = []
    for _ in range(max_looks):
        goal = target_cam @ invert_pose(T_ee_cam)
        qn = move_to(goal, qc)
        if qn is None:
            return fail("pre-grasp pose unreachable", vis, switch.switches, looks)
        qc = qn
        F = mm.arm.fk(qc) @ T_ee_cam
        px = eye.observe(T_world_arm @ F)
        if px is None:
            return fail("mark lost during look-then-move", vis, switch.switches, looks)
        looks += 1
        estimates.append(next_look(F, px, taught, plane, K, dist))
        E = np.array(estimates)
        mean = np.eye(4)
        mean[:3, :3] = nearest_rotation(E[:, :3, :3].mean(axis=0))
        mean[:3, 3] = E[:, :3, 3].mean(axis=0)
        dp, dr = pose_error(mean, target_cam)
        target_cam = mean
        if len(estimates) >= 3 and dp < 2e-4 and dr < math.radians(0.02):
            break
    # Descend along the approach to the grasp, close, lift, carry.
    enter("grasp")
    pre = target_cam @ invert_pose(T_ee_cam)
    grasp_pose = pre.copy()
    grasp_pose[:3, 3] += PRE_GRASP * pre[:3, 2]
    qg = move_to(grasp_pose, qc)
    if qg is None:
        return fail("grasp pose unreachable", vis, switch.switches, looks)
    achieved = T_world_arm @ mm.arm.fk(qg)
    dp, dr = pose_error(achieved, T_mark @ T_MARK_GRASP)
    # Close: the fingers stop on the box (or close on nothing).
    opening, missed = close_gripper(achieved, T_mark)
    t += (GRIPPER_OPEN - opening) / GRIPPER_SPEED
    if on_gripper is not None:
        on_gripper(opening)
    if missed:
        return GraspEpisode(
            False,
            1e3 * float(dp),
            math.degrees(float(dr)),
            t,
            vis,
            switch.switches,
            looks,
            missed,
            phase,
            1e3 * opening,
            eye.frames,
        )
    held = invert_pose(achieved) @ T_mark
    held[1, 3] = 0.0  # the closing fingers pushed it onto their midline (close_gripper)
    if on_box is not None:
        on_box(mm.arm.fk(qg) @ held)
    enter("lift and carry")
    lift = grasp_pose.copy()
    lift[2, 3] += 0.10
    if move_to(lift, qg) is None:
        return fail("lift unreachable", vis, switch.switches, looks)
    t += 0.5 / 0.5  # carry 0.5 m at 0.5 m/s
    # Scored against the twin once carried (the robot cannot tell): a grasp off by more than
    # the tolerance failed in the grasp phase.
    ok = bool(dp < 5e-3 and dr < math.radians(2.0))
    return GraspEpisode(
        success=ok,
        position_error_mm=1e3 * float(dp),
        rotation_error_deg=math.degrees(float(dr)),
        time_s=t,
        visible_fraction=vis,
        switches=switch.switches,
        looks=looks,
        reason="" if ok else "final pose error above 5 mm / 2 deg",
        phase=phase if ok else "grasp",
        gripper_opening_mm=1e3 * opening,
        frames=eye.frames,
    )


@dataclass(frozen=True)
class FetchPreparation:
    """What a fetch's episodes use, prepared once (`prepare_fetch`): the eye-in-hand camera's
    own calibration, the hand-eye transform X = T_ee_cam (4, 4) they servo with and where it
    came from ("calibrated": from 15 views, refined; "arm": the one applied to the arm), and
    the mark's taught ideal pixels (M, 2)."""

    intrinsics: RenderedCalibration
    X: Array
    hand_eye_source: str
    taught: Array


HAND_EYE_VIEWS = 15


def prepare_fetch(
    rng: np.random.Generator,
    mm: MobileManipulator,
    *,
    sigma_px: float,
    renderer: Renderer | None,
    X: Array | None = None,
    on_stage: Callable[[str], None] | None = None,
) -> FetchPreparation:
    """Return what the fetch's episodes need, drawn from `rng` in this order: the eye-in-hand
    camera's intrinsics (eye_camera_intrinsics), the hand-eye transform (HAND_EYE_VIEWS views
    of the table's chessboard, calibrated by core.manipulation.calibrate_hand_eye and refined by
    reprojection) unless the arm's applied one is given as `X`, and the taught image
    (taught_image, the camera where the arm truly holds it). With a `renderer` every image is
    rendered by the twin and its corners detected; without one, the true projections; both with
    N(0, sigma_px^2) noise. `on_stage(name)` is called before the calibration ("calibrating the
    eye-in-hand camera") and the teaching ("teaching the mark")."""
    intrinsics = eye_camera_intrinsics(rng)
    source = "arm"
    if X is None:
        if on_stage is not None:
            on_stage("calibrating the eye-in-hand camera")
        v = hand_eye_views(
            rng,
            views=HAND_EYE_VIEWS,
            sigma_px=sigma_px,
            manipulator=mm,
            rendered=renderer is not None,
            renderer=renderer,
            intrinsics=intrinsics,
        )
        X = calibrate_hand_eye(
            v.T_base_ee,
            v.T_cam_target,
            object_points=v.object_points,
            image_points=v.image_points,
            K=v.K,
            dist=v.dist,
        ).X
        source = "calibrated"
    if on_stage is not None:
        on_stage("teaching the mark")
    taught = taught_image(mm.T_ee_camera, intrinsics, renderer=renderer, rng=rng, sigma_px=sigma_px)
    return FetchPreparation(intrinsics, np.asarray(X, dtype=np.float64), source, taught)


def fetch_episodes(
    rng: np.random.Generator,
    mm: MobileManipulator,
    prepared: FetchPreparation,
    episodes: int,
    *,
    sigma_px: float,
    renderer: Renderer | None,
    on_phase: Callable[[int, str], None] | None = None,
    T_world_prior: Array | None = None,
    on_joints: Callable[[Array], None] | None = None,
    on_gripper: Callable[[float], None] | None = None,
    on_box: Callable[[Array], None] | None = None,
) -> Iterator[GraspEpisode]:
    """Yield `episodes` fetches (grasp_episode) one after the other, on `rng` after
    prepare_fetch's draws, each with the prepared hand-eye transform, intrinsics and taught
    image; `on_phase(k, name)` as episode k (from 0) enters each of its phases (GRASP_PHASES);
    `T_world_prior`, `on_joints`, `on_gripper` and `on_box` go to every episode."""
    for k in range(episodes):
        yield grasp_episode(
            rng,
            mm,
            prepared.X,
            intrinsics=prepared.intrinsics,
            sigma_px=sigma_px,
            on_phase=None if on_phase is None else partial(on_phase, k),
            T_world_prior=T_world_prior,
            on_joints=on_joints,
            renderer=renderer,
            taught=prepared.taught,
            on_gripper=on_gripper,
            on_box=on_box,
        )
