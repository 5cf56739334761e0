"""Mobile manipulation in the service: arms from the registry as core's kinematic models (and
as the API shows them), and fetch tasks run on the twin in background threads with their phase
and result stored as they go. Hand-eye runs are server.services.calibration.hand_eye.

The twin's simulated eye-in-hand camera sits where core.manipulation's default manipulator
mounts it; that true mount only renders (or projects) what the camera sees and scores the
results, as in core.sim.scenarios.manipulation: no estimate reads it.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from core.errors import IntspaceError, InvalidInput
from core.manipulation import (
    DHArm,
    MobileManipulator,
    default_manipulator,
    pose_error,
)
from core.sim.fetch import (
    GRASP_PHASES,
    GraspEpisode,
    fetch_episodes,
    prepare_fetch,
)
from core.sim.fetch_placement import fetch_problem
from core.sim.render import Renderer
from core.sim.scene import default_scene
from server.db.base import utcnow
from server.db.models import Arm, SemanticObject, Task
from server.schemas.common import ReadSchema, stored_json
from server.schemas.manipulation import (
    ArmRead,
    EpisodePhase,
    FetchEpisodeRead,
    FetchHandEye,
    FetchResult,
)
from server.services.jobs import (
    JobCancelled,
    JobEngine,
    JobTable,
    Lease,
    LeasePolicy,
    failure,
)

if TYPE_CHECKING:
    from server.services.scene_sync import SceneSync

log = logging.getLogger(__name__)

Progress = Callable[[str, float], None]
Problem = tuple[str, str]  # (field, reason)

# --------------------------------------------------------------------------------------------
# Arms

_KINEMATICS = ("dh", "limits", "tool", "home", "T_robot_arm", "T_ee_camera")


@dataclass(frozen=True)
class ArmKinematics:
    """An arm's kinematic fields as stored (JSON-ready lists): its DH parameters ({a, d, alpha,
    offset}), joint limits, tool, home configuration, mount on the robot (T_robot_arm) and
    applied hand-eye transform (T_ee_camera, None when it has none)."""

    dh: dict[str, list[float]]
    limits: list[list[float]]
    tool: list[list[float]]
    home: list[float]
    T_robot_arm: list[list[float]]
    T_ee_camera: list[list[float]] | None

    @classmethod
    def of(cls, arm: Arm) -> ArmKinematics:
        """Return an arm row's kinematic fields."""
        return cls.from_json({key: getattr(arm, key) for key in _KINEMATICS})

    @classmethod
    def from_json(cls, values: Mapping[str, Any]) -> ArmKinematics:
        """Return the kinematic fields stored as JSON (a task's or a run's inputs["arm"];
        T_ee_camera may be absent)."""
        return cls(
            dh=values["dh"],
            limits=values["limits"],
            tool=values["tool"],
            home=values["home"],
            T_robot_arm=values["T_robot_arm"],
            T_ee_camera=values.get("T_ee_camera"),
        )

    def as_json(self) -> dict[str, Any]:
        """Return the fields as stored in a task's or a run's inputs."""
        return asdict(self)


_COLUMNS = tuple(name for name in ArmRead.model_fields if name != "closed_form")


def arm_read(arm: Arm) -> ArmRead:
    """Return an arm as the API shows it (with whether it has the closed-form IK)."""
    data: dict[str, Any] = {name: getattr(arm, name) for name in _COLUMNS}
    return ArmRead.model_validate({**data, "closed_form": closed_form(ArmKinematics.of(arm))})


def dh_arm(values: ArmKinematics, name: str = "arm") -> DHArm:
    """Return core's DHArm of stored arm fields (raises InvalidInput when they do not make
    one)."""
    dh = values.dh
    return DHArm(
        name=name,
        a=np.asarray(dh["a"], dtype=float),
        d=np.asarray(dh["d"], dtype=float),
        alpha=np.asarray(dh["alpha"], dtype=float),
        offset=np.asarray(dh.get("offset", [0.0] * 6), dtype=float),
        limits=np.asarray(values.limits, dtype=float),
        tool=np.asarray(values.tool, dtype=float),
        home=np.asarray(values.home, dtype=float),
    )


def arm_model_problem(values: ArmKinematics) -> Problem | None:
    """Return (field, reason) when stored arm fields do not form a usable arm (the home
    configuration outside the limits, or anything core refuses), None when they do."""
    home = np.asarray(values.home, dtype=float)
    limits = np.asarray(values.limits, dtype=float)
    outside = np.flatnonzero((home < limits[:, 0]) | (home > limits[:, 1]))
    if outside.size:
        j = int(outside[0])
        return (
            f"home.{j}",
            f"joint {j + 1}'s home value {home[j]:g} rad is outside its limits "
            f"[{limits[j, 0]:g}, {limits[j, 1]:g}]; the numerical IK starts from home",
        )
    try:
        dh_arm(values)
    except InvalidInput as exc:
        return ("dh", str(exc))
    return None


def closed_form(values: ArmKinematics) -> bool:
    """Return whether the stored arm has the Puma-type closed-form inverse kinematics."""
    return dh_arm(values).has_closed_form


def twin_manipulator(values: ArmKinematics) -> MobileManipulator:
    """Return the registry arm as the twin simulates it: its geometry and mount, with the
    eye-in-hand camera where the twin's camera truly is (for rendering and scoring only)."""
    return MobileManipulator(
        arm=dh_arm(values),
        T_base_arm=np.asarray(values.T_robot_arm, dtype=float),
        T_ee_camera=default_manipulator().T_ee_camera,
    )


# --------------------------------------------------------------------------------------------
# Fetch tasks

PHASES = GRASP_PHASES  # approach, switch, look then move, grasp, lift and carry


def episode_phases(episode: GraspEpisode) -> list[EpisodePhase]:
    """Return the phases an episode went through, the failed one last (the phase core.sim's
    grasp episode records it failed in)."""
    if episode.success:
        return [EpisodePhase(name=p, ok=True) for p in PHASES]
    k = PHASES.index(episode.phase)
    return [EpisodePhase(name=p, ok=i < k) for i, p in enumerate(PHASES[: k + 1])]


def _finite(x: float) -> float | None:
    return None if not math.isfinite(x) else float(x)


def episode_record(episode: GraspEpisode) -> FetchEpisodeRead:
    """Return an episode as stored: outcome, phases, final errors and diagnostics."""
    return FetchEpisodeRead(
        success=episode.success,
        phases=episode_phases(episode),
        position_error_mm=_finite(episode.position_error_mm),
        rotation_error_deg=_finite(episode.rotation_error_deg),
        time_s=episode.time_s,
        visible_fraction=episode.visible_fraction,
        switches=episode.switches,
        looks=episode.looks,
        reason=episode.reason,
        gripper_opening_mm=_finite(episode.gripper_opening_mm),
        frames=episode.frames,
    )


def _median(values: list[float | None]) -> float | None:
    known = [v for v in values if v is not None]
    return float(np.median(known)) if known else None


def fetch_summary(
    records: list[FetchEpisodeRead], planned: int, hand_eye: FetchHandEye, seed: int
) -> FetchResult:
    """Return the stored result of a fetch task from its episodes so far: success rate, medians
    over successes of the final errors, median time, failure reasons with counts."""
    good = [r for r in records if r.success]
    failures: dict[str, int] = {}
    for r in records:
        if not r.success:
            failures[r.reason] = failures.get(r.reason, 0) + 1
    return FetchResult(
        episodes=len(records),
        planned=planned,
        successes=len(good),
        success_rate=len(good) / len(records) if records else None,
        position_error_m=_median(
            [None if r.position_error_mm is None else r.position_error_mm / 1e3 for r in good]
        ),
        rotation_error_deg=_median([r.rotation_error_deg for r in good]),
        time_s=_median([r.time_s for r in records]),
        failures=failures,
        hand_eye=hand_eye,
        seed=seed,
        per_episode=records,
    )


class FetchRefused(Exception):
    """A fetch that cannot start: `status` (404: the object is not in the semantic map; 409:
    its name is ambiguous, or it is out of reach), the request field at fault and the reason."""

    def __init__(self, status: int, field: str, reason: str) -> None:
        super().__init__(reason)
        self.status = status
        self.field = field


@dataclass(frozen=True)
class FetchObject:
    """The object a fetch takes, as the space's semantic map holds it: its mark's id, name,
    class and pose (T_world_mark, 4x4 nested lists)."""

    id: int
    name: str
    object_class: str
    T_world_mark: list[list[float]]

    @classmethod
    def from_json(cls, values: Mapping[str, Any]) -> FetchObject:
        """Return the object stored in a task's inputs (as_json's)."""
        return cls(values["id"], values["name"], values["class"], values["T_world_mark"])

    def as_json(self) -> dict[str, Any]:
        """Return the object as a task's inputs store it."""
        return {
            "id": self.id,
            "name": self.name,
            "class": self.object_class,
            "T_world_mark": self.T_world_mark,
        }


@dataclass(frozen=True)
class FetchInputs:
    """What a fetch task runs from, read from its stored inputs: the seed, the episodes
    planned, the pixel noise, the arm's fields at submission and the object (None: a box
    placed at random)."""

    seed: int
    episodes: int
    sigma_px: float
    arm: ArmKinematics
    object: FetchObject | None

    @classmethod
    def from_json(cls, inputs: Mapping[str, Any]) -> FetchInputs:
        """Return the inputs a task stores (POST /tasks builds them)."""
        target = inputs.get("object")
        return cls(
            seed=int(inputs["seed"]),
            episodes=int(inputs["episodes"]),
            sigma_px=float(inputs["sigma_px"]),
            arm=ArmKinematics.from_json(inputs["arm"]),
            object=None if target is None else FetchObject.from_json(target),
        )


def fetch_target(
    session: Session, space_id: int, ref: int | str, values: ArmKinematics
) -> FetchObject:
    """Return the object a fetch takes, as the space's semantic map holds it; `ref` is its id
    (int) or its name (str, any case).
    Raises FetchRefused: 404 when the map has no such object, 409 when two have that name or
    the arm cannot fetch it from there (core.sim.fetch_placement.fetch_problem)."""
    query = (
        select(SemanticObject)
        .where(SemanticObject.space_id == space_id)
        .order_by(SemanticObject.mark_id)
    )
    if isinstance(ref, int):
        rows = list(session.scalars(query.where(SemanticObject.mark_id == ref)))
    else:
        wanted = ref.strip().casefold()
        rows = [r for r in session.scalars(query) if r.name.casefold() == wanted]
    if not rows:
        known = session.execute(
            select(SemanticObject.mark_id, SemanticObject.name)
            .where(SemanticObject.space_id == space_id)
            .order_by(SemanticObject.mark_id)
        ).all()
        listing = ", ".join(f"{i} ({n})" for i, n in known) or "none yet"
        raise FetchRefused(
            404,
            "object",
            f"no object {ref!r} in the semantic map of space {space_id} (objects: {listing}); "
            "give an id or name from GET /maps/semantic",
        )
    if len(rows) > 1:
        ids = ", ".join(str(r.mark_id) for r in rows)
        raise FetchRefused(
            409, "object", f"{len(rows)} objects are called {ref!r} (ids {ids}); give the id"
        )
    row = rows[0]
    problem = fetch_problem(twin_manipulator(values), np.asarray(row.T_world_mark))
    if problem is not None:
        raise FetchRefused(
            409, "object", f"object {row.mark_id} ({row.name}) cannot be fetched: {problem}"
        )
    return FetchObject(row.mark_id, row.name, row.object_class, row.T_world_mark)


Report = Callable[[str, float, ReadSchema | None], None]


def run_fetch(
    inputs: FetchInputs,
    report: Report,
    joints: Callable[[np.ndarray], None] | None = None,
    gripper: Callable[[float], None] | None = None,
    box: Callable[[np.ndarray], None] | None = None,
) -> FetchResult:
    """Run a fetch task and return its result; `report(phase, fraction, partial result)` is
    called as each episode enters each of its phases ("episode 2 of 5: look then move", the
    controller's own calls) and with the result so far after each episode; `joints(q)` each
    time the arm moves, `gripper(opening)` (m) each time the gripper opens or closes and
    `box(T_arm_box)` each time the twin's box moves relative to the arm's base (its mark frame
    in the arm's base frame, before the joints of the same step: grasp_episode's on_box). With
    inputs.object (fetch_target's), every episode fetches the box at the pose the semantic
    map holds (the twin's box lies off it by the map's error).

    Every eye-in-hand image is rendered by the twin and the mark detected in it. The hand-eye
    calibration (when the arm has none applied), the taught image and the episodes draw from
    one generator seeded by inputs.seed, in the order of `intspace sim run grasp`: with the
    twin's arm and no applied hand-eye, a task's episodes are that scenario's."""
    seed = inputs.seed
    planned = inputs.episodes
    sigma = inputs.sigma_px
    rng = np.random.default_rng(seed)
    mm = twin_manipulator(inputs.arm)
    renderer = Renderer(default_scene(), supersample=1)
    target = inputs.object
    applied = inputs.arm.T_ee_camera
    prepared = prepare_fetch(
        rng,
        mm,
        sigma_px=sigma,
        renderer=renderer,
        X=None if applied is None else np.asarray(applied, dtype=float),
        on_stage=lambda stage: report(stage, 0.0, None),
    )
    dp, dr = pose_error(prepared.X, mm.T_ee_camera)  # scoring only
    hand_eye = FetchHandEye(
        source=prepared.hand_eye_source,
        rotation_error_deg=math.degrees(float(dr)),
        translation_error_mm=1e3 * float(dp),
    )
    records: list[FetchEpisodeRead] = []

    def entered(k: int, name: str) -> None:
        fraction = (k + PHASES.index(name) / len(PHASES)) / planned
        # The result so far goes with the next episode's first phase.
        partial = None
        if name == PHASES[0] and records:
            partial = fetch_summary(records, planned, hand_eye, seed)
        report(f"episode {k + 1} of {planned}: {name}", fraction, partial)

    for episode in fetch_episodes(
        rng,
        mm,
        prepared,
        planned,
        sigma_px=sigma,
        renderer=renderer,
        on_phase=entered,
        T_world_prior=None if target is None else np.asarray(target.T_world_mark),
        on_joints=joints,
        on_gripper=gripper,
        on_box=box,
    ):
        records.append(episode_record(episode))
    return fetch_summary(records, planned, hand_eye, seed)


# A task is held by the process that accepted it from then on, queued until one of its
# workers is free; a task whose process stopped is interrupted, never run again elsewhere.
TASKS = JobTable(
    model=Task,
    status=Task.status,
    running="running",
    held=("queued", "running"),
    expired_reason="the process running it stopped before it finished",
    expired_status="interrupted",
)
TASK_LEASES = LeasePolicy(lease_s=60.0, heartbeat_s=5.0, max_attempts=1)


@dataclass(frozen=True)
class ArmMotion:
    """What shows a task's arm in the 3D scene, run_fetch's reporters: `joints(q)`,
    `gripper(opening)` and `box(T_arm_box)`; all None when there is no scene or no arm."""

    joints: Callable[[np.ndarray], None] | None = None
    gripper: Callable[[float], None] | None = None
    box: Callable[[np.ndarray], None] | None = None


class TaskRunner(JobEngine):
    """Runs tasks in background threads of the API process (`workers` at a time; the others
    wait queued), each held under a lease from the moment it is accepted (`lease()`): a task
    whose process stopped renewing it reads as interrupted. With the live 3D scene (`scene`),
    a task's arm is drawn on the robot the scene shows, with the box it fetches."""

    def __init__(
        self,
        factory: sessionmaker[Session],
        workers: int = 1,
        *,
        policy: LeasePolicy = TASK_LEASES,
        scene: SceneSync | None = None,
    ) -> None:
        self.factory = factory
        self.scene = scene
        super().__init__(factory, TASKS, self._run, workers, policy, name="task")

    def lease(self) -> dict[str, Any]:
        """Return the lease columns of a task this runner accepts now (then `submit` it)."""
        return self.policy.lease(self.owner)

    def submit(self, task_id: int) -> None:
        """Run committed task `task_id`, stored with this runner's `lease()`, when a worker
        thread is free."""
        self.hold(task_id)

    def _run(self, lease: Lease) -> str | None:
        task_id = lease.job_id
        arm: Arm | None = None
        try:
            with self.factory() as session:
                task = session.get(Task, task_id)
                inputs = dict(task.inputs) if task is not None else None
                kind = task.kind if task is not None else None
                arm = None if task is None or task.arm_id is None else session.get(Arm, task.arm_id)
                if arm is not None and self.scene is not None:
                    self.scene.arm_changed(arm)  # at home, as the task starts
            if inputs is None:
                return None
            lease.write(status="running", started_at=utcnow(), progress=0.0)

            def report(phase: str, fraction: float, partial: ReadSchema | None) -> None:
                values: dict[str, Any] = {"phase": phase[:80], "progress": fraction}
                if partial is not None:
                    values["result"] = stored_json(partial)
                lease.write(**values)

            outcome: dict[str, Any]
            try:
                result = self._execute(str(kind), inputs, report, arm)
                outcome = {
                    "status": "succeeded",
                    "result": stored_json(result),
                    "phase": "done",
                }
                outcome["progress"] = 1.0
            except JobCancelled:
                raise
            except Exception as exc:
                outcome = {"status": "failed", "error": failure(exc, f"task {task_id}")}
            with self.factory() as session:
                return str(outcome["status"]) if lease.finish(session, **outcome) else None
        except JobCancelled:  # stopping: the runner marks it interrupted
            return None
        finally:
            if arm is not None and self.scene is not None:
                # However it ended, the arm is idle: the box it fetched gone, back at home.
                self.scene.arm_box_removed(arm.id)
                self.scene.arm_changed(arm)

    def _execute(
        self, kind: str, inputs: dict[str, Any], report: Report, arm: Arm | None
    ) -> ReadSchema:
        """Run one task of `kind` from its stored inputs (a JSON column, each kind's own
        fields) and return its result; a runner that knows more kinds extends this."""
        if kind != "fetch":
            raise IntspaceError(f"this service cannot run {kind!r} tasks")
        motion = self._arm_motion(arm)
        return run_fetch(
            FetchInputs.from_json(inputs), report, motion.joints, motion.gripper, motion.box
        )

    def _arm_motion(self, arm: Arm | None) -> ArmMotion:
        """Return what shows a task's arm moving in the 3D scene: its joints, at most 10
        times a second (the twin runs the fetch faster than the clock), with the box where
        the step that moved them put it, and its gripper opening and closing."""
        scene = self.scene
        if scene is None or arm is None:
            return ArmMotion()
        arm_id = arm.id
        last = -math.inf
        pending: list[np.ndarray] = []  # the box's latest pose, not shown yet

        def show(q: np.ndarray) -> None:
            nonlocal last
            now = time.monotonic()
            if now - last >= 0.1:
                last = now
                scene.arm_joints(arm_id, q)
                if pending:
                    scene.arm_box(arm_id, pending.pop())

        def hold(T_arm_box: np.ndarray) -> None:
            # Shown with the joints that follow it (the episode reports the box first): a box
            # in the gripper sent alone would be drawn a control step off the fingers.
            pending[:] = [T_arm_box]

        def grip(opening: float) -> None:
            scene.arm_gripper(arm_id, opening)

        return ArmMotion(joints=show, gripper=grip, box=hold)

    def shutdown(self, reason: str = "the service stopped during it") -> int:
        """Stop: the running tasks end at their next phase, and every task this process held
        is marked interrupted with `reason`; return how many."""
        return super().shutdown(reason)
