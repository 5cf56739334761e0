"""Survey tasks on the digital twin: the robot tours the twin's home, reads the landmarks it
finds and enters them into the space's semantic and navigation maps as it goes.

The tour is core.sim's `landmark-survey` (core.sim.scenarios.landmark_survey.landmark_survey) on the
twin's scene, from the robot's start pose: routes planned on the floor plan, head sweeps at
every stop, PBVS reads of the landmarks located but not yet read, the odometry corrected at
signposts. Every read enters the maps through the same service as POST /maps/observations
(server.services.landmarks.observe): object marks fused into their entry, signposts as places.
The task runs in a background thread of the task runner, its phase, progress and result so far
stored as it goes and read back with GET /tasks/{id}. The twin's true landmark poses only
score the result (`truth`), as in the scenario.
"""

from __future__ import annotations

import logging
import secrets
import time
from typing import Any, Literal

from pydantic import Field

from core.errors import IntspaceError
from core.landmarks.payload import ObjectMark
from core.sim import Scene, default_scene
from core.sim.scenarios.landmark_survey import DEFAULT_TOUR, SurveyRead, landmark_survey
from server.db.models import Task
from server.schemas.common import ReadSchema, Schema
from server.schemas.manipulation import FetchResult, TaskRead
from server.services.landmarks import MapObservation, observe
from server.services.manipulation import Report, TaskRunner

log = logging.getLogger(__name__)


class SurveyTaskCreate(Schema):
    """Survey the twin's home: the robot drives its tour (the home's survey tour, or the
    robot's patrol waypoints in another scene), reads every landmark it can and writes what it
    reads into the twin space's semantic and navigation maps (GET /maps/semantic,
    GET /maps/navigation). A whole tour is about 10 simulated minutes (several minutes of
    computing); `duration_s` cuts it short."""

    kind: Literal["survey"]
    duration_s: float | None = Field(
        None,
        gt=0,
        le=3600,
        allow_inf_nan=False,
        description="Stop after this many simulated seconds (default: the whole tour).",
    )
    seed: int | None = Field(None, ge=0, le=2**31 - 1, description="Drawn when absent.")


class SurveyEntry(ReadSchema):
    """A landmark the survey entered into a map: which map, the mark's id, its name and room,
    where it was put (x, y, z metres; for a place, the pose its signpost carries) and how
    many times it was read."""

    map: Literal["semantic", "navigation"]
    mark_id: int
    name: str
    room: str
    position: list[float]
    reads: int


class SurveyTruth(ReadSchema):
    """A finished survey's figures against the twin's truth (core.sim's LandmarkSurveyResult):
    object marks and signpost places present, seen and found, the semantic map's mean and max
    position error (m), false and duplicate entries, landmarks seen but not read."""

    objects_present: int
    objects_seen: int
    objects_found: int
    places_present: int
    places_seen: int
    places_found: int
    position_error_mean_m: float | None
    position_error_max_m: float | None
    false_entries: int
    duplicate_entries: int
    seen_not_read: list[str]


class SurveyResult(ReadSchema):
    """What a survey found so far (filled read by read) and, once done, its figures against
    the twin's truth (`truth`: objects and places present, seen and found, mean and max
    position error, false and duplicate entries, landmarks seen but not read)."""

    space_id: int
    seed: int
    duration_s: float | None
    entries: list[SurveyEntry]
    reads: int = Field(description="Reads entered into the maps so far.")
    time_s: float | None = Field(description="Simulated seconds the survey took (when done).")
    completed: bool | None = Field(description="Whether it drove the whole tour (when done).")
    reads_attempted: int | None = None
    reads_succeeded: int | None = None
    collided: bool | None = None
    truth: SurveyTruth | None = None


class AnyTaskRead(TaskRead):
    """A task as read back: a fetch's result or a survey's."""

    result: FetchResult | SurveyResult | None  # type: ignore[assignment]


def survey_tour(scene: Scene) -> tuple[tuple[float, float], ...] | None:
    """Return the tour for a scene: the default home's survey tour for the default home, else
    None (the robot's patrol waypoints)."""
    return DEFAULT_TOUR if scene.name == default_scene().name else None


def _entry(read: SurveyRead, reads: int) -> SurveyEntry:
    rec = read.record
    if isinstance(rec, ObjectMark):
        position = [float(v) for v in read.T_world_mark[:3, 3]]
        which: Literal["semantic", "navigation"] = "semantic"
    else:
        position = [float(v) for v in rec.pose[:3]]
        which = "navigation"
    return SurveyEntry(
        map=which, mark_id=rec.id, name=rec.name, room=rec.room, position=position, reads=reads
    )


def run_survey(
    seed: int,
    duration: float | None,
    scene: Scene,
    space_id: int,
    factory: Any,
    report: Report,
) -> SurveyResult:
    """Run a survey task on `scene` with `seed`, cut short after `duration` simulated seconds
    (None: the whole tour), and return its result; every read enters the maps of space
    `space_id` (a session from `factory` per read) as it is made; `report(phase, fraction,
    partial result)` is called as the survey goes."""
    entries: dict[tuple[str, int], SurveyEntry] = {}
    count = 0

    def partial() -> SurveyResult:
        return SurveyResult(
            space_id=space_id,
            seed=seed,
            duration_s=duration,
            entries=sorted(entries.values(), key=lambda e: (e.map, e.mark_id)),
            reads=count,
            time_s=None,
            completed=None,
        )

    phase = "starting"
    done = 0.0

    def on_progress(what: str, fraction: float) -> None:
        nonlocal phase, done
        phase, done = what, fraction
        report(what, fraction, partial())

    def on_read(read: SurveyRead) -> None:
        nonlocal count
        # Wall-clock time: the maps' `last_seen` is when the service learnt it.
        obs = MapObservation(read.record, read.T_world_mark, read.cov, time.time())
        with factory() as session:
            observe(session, space_id, [obs])
        count += 1
        key = ("semantic" if read.record.kind == "object" else "navigation", read.record.id)
        before = entries.get(key)
        entries[key] = _entry(read, 1 if before is None else before.reads + 1)
        report(phase, done, partial())

    result = landmark_survey(
        scene,
        seed,
        tour=survey_tour(scene),
        duration_s=duration,
        on_progress=on_progress,
        on_read=on_read,
    )
    return SurveyResult(
        space_id=space_id,
        seed=seed,
        duration_s=duration,
        entries=partial().entries,
        reads=count,
        time_s=result.time_s,
        completed=result.completed,
        reads_attempted=result.reads_attempted,
        reads_succeeded=result.reads_succeeded,
        collided=result.collided,
        truth=SurveyTruth(
            **{
                name: getattr(result, name)
                for name in SurveyTruth.model_fields
                if name != "seen_not_read"
            },
            seen_not_read=list(result.seen_not_read),
        ),
    )


class TwinTaskRunner(TaskRunner):
    """The task runner of the service: fetch tasks as TaskRunner runs them, and survey tasks
    (run_survey) on the twin given at construction, with the same status, phase, lease and
    interruption handling."""

    def __init__(self, factory: Any, *args: Any, twin: Any = None, **kwargs: Any) -> None:
        self.twin = twin
        super().__init__(factory, *args, **kwargs)

    def _execute(self, kind: str, inputs: dict[str, Any], report: Report, arm: Any) -> ReadSchema:
        if kind != "survey":
            return super()._execute(kind, inputs, report, arm)
        twin = self.twin
        if twin is None or twin.space_id is None:
            raise IntspaceError("the twin stopped before the survey could start")
        # The task's stored inputs (survey_task's): the seed drawn, the duration asked for.
        seed, duration = int(inputs["seed"]), inputs.get("duration_s")
        result = run_survey(seed, duration, twin.scene, twin.space_id, self.factory, report)
        if self.scene is not None:
            with self.factory() as session:
                self.scene.maps_changed(session)
        return result


def survey_task(session: Any, body: SurveyTaskCreate, lease: dict[str, Any]) -> Task:
    """Return the queued survey task stored for `body` (the seed drawn when absent) under
    `lease` (its runner's, TaskRunner.lease)."""
    inputs = body.model_dump()
    if inputs["seed"] is None:
        inputs["seed"] = secrets.randbelow(2**31)
    task = Task(
        kind=body.kind,
        status="queued",
        inputs=inputs,
        phase="queued",
        progress=0.0,
        **lease,
    )
    session.add(task)
    session.commit()
    return task
