"""Batched detections in: stored, fed to the space's tracker, and labelled groups located at once.

POST /observations takes the detections of any cameras (spec 08: unlabelled, several per camera
frame, each with its kind where the sender knows it). They are committed to the detections
table before the answer, then queued for the tracker of the cameras' space
(server.services.tracking), which makes and follows the targets. A batch may also list camera
frames in which nothing was detected (`empty_frames`: camera and capture time); they are not
stored, but reach the tracker, which then knows it need not wait for those cameras' frames up
to those times, so the tracks follow with the delay of the slowest camera instead of the
tracker's whole reorder window. A detection may be a detector's box instead of a pixel (any
detector: Frigate's, a user's own): its foot point and covariance come from
core.localization.box_foot, a box scored below its camera's `score_threshold` is dropped, and
one whose bottom is cut is stored but not tracked. Detections that carry a
`target` label are also located at once by maximum likelihood on the plane, per (target, t),
and returned, as before the tracker existed.
"""

from __future__ import annotations

import time
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, status
from fastapi.responses import JSONResponse

from server.api.deps import SessionDep, get_live_targets, get_tracking, require_write
from server.api.errors import PROBLEM_RESPONSES, FieldProblem
from server.api.server_time import SERVER_TIME_HEADER
from server.schemas.localization import EmptyFrame, Observation, ObservationBatch, PositionBatch
from server.services.auth import Principal
from server.services.cameras import registry_cameras
from server.services.observations import (
    ObservationRefused,
    camera_rows,
    detections_in,
    drop_unseen_robots,
    locate_labelled,
    measure,
)
from server.services.targets import LiveTargets
from server.services.tracking import TrackingService

router = APIRouter(tags=["localization"], responses=PROBLEM_RESPONSES)

# Live labelled targets a space may hold: every distinct label is a live target until it has
# been silent for the tracker's labelled_end_after (60 s), and each is in every stream tick. A
# home labels a few bodies; 40,000 labels made each tick 7.8 MB.
MAX_LIVE_LABELS = 256
# How long a silent labelled target stays live (core TrackerConfig.labelled_end_after), s.
LABEL_RETIRES_AFTER_S = 60


@router.post("/observations", response_model=PositionBatch)
def post_observations(
    body: ObservationBatch,
    session: SessionDep,
    who: Annotated[Principal | None, Depends(require_write)],
    tracking: Annotated[TrackingService | None, Depends(get_tracking)],
    live: Annotated[LiveTargets | None, Depends(get_live_targets)],
):
    """Store the batch's detections and queue them for the space's tracker; return how many
    were stored and queued, and the floor position of each labelled (target, t): its
    detections from every camera fused by maximum likelihood on the plane Z = height
    (core.localization.locate_ml). Every camera must have intrinsics and a pose; a camera may
    see a labelled (target, t) once; unlabelled detections may be many per camera frame. An
    empty frame (camera, t) says the camera saw nothing at t: the same camera and time must
    not also have detections in the batch, nor be listed twice."""
    obs = body.observations
    empty = body.empty_frames
    camera_ids = sorted({o.camera_id for o in obs} | {f.camera_id for f in empty})
    cameras, refused = registry_cameras(session, camera_ids)
    for index, o in enumerate(obs):
        if o.camera_id in refused:
            raise FieldProblem(
                422,
                f"observations.{index}.camera_id",
                f"{refused[o.camera_id]}; calibrate and pose it before sending its detections",
            )
    _check_empty_frames(obs, empty, refused, who)
    rows = camera_rows(session, camera_ids)
    space_of = {cid: row.space_id for cid, row in rows.items()}
    obs, empty, ignored = drop_unseen_robots(session, obs, empty, space_of)
    try:
        m = measure(obs, rows, cameras, space_of, tracking)
        if live is not None:
            _check_labels(obs, space_of, live)
        labelled = [
            i for i, o in enumerate(obs) if o.target is not None and m.keep[i] and m.tracked[i]
        ]
        positions = locate_labelled(obs, labelled, cameras, m) if labelled else []
    except ObservationRefused as exc:
        raise FieldProblem(422, exc.field, str(exc)) from exc
    detections = detections_in(obs, m)
    if tracking is not None:
        marks = [(f.camera_id, f.t) for f in empty]
        result = tracking.ingest(session, detections, space_of, empty=marks)
        stored, frames, late = result.stored, result.frames, result.late
    else:  # pragma: no cover - the app always has its tracking service once started
        stored, frames, late = 0, 0, 0
    answer = {
        "stored": stored,
        "frames": frames,
        "late": late,
        "ignored": len(ignored),
        "positions": positions,
    }
    # The service's clock to the microsecond: a camera node measures its clock offset by it
    # (the Date header has whole seconds, refreshed late when the service is loaded).
    return JSONResponse(answer, headers={SERVER_TIME_HEADER: f"{time.time():.6f}"})


def _check_empty_frames(
    obs: list[Observation],
    empty: list[EmptyFrame],
    refused: dict[int, str],
    who: Principal | None,
) -> None:
    """Refuse empty frames of unusable cameras, of cameras an ingest token does not speak for
    (403), listed twice, or of a camera and time that also has detections in the batch."""
    seen: set[tuple[int, float]] = set()
    detected = {(o.camera_id, o.t) for o in obs}
    for index, f in enumerate(empty):
        where = f"empty_frames.{index}"
        if who is not None and not who.speaks_for(f.camera_id):
            raise HTTPException(
                status.HTTP_403_FORBIDDEN,
                detail=f"this ingest token speaks for cameras {sorted(who.camera_ids or ())} "
                f"only, not {f.camera_id} ({where})",
            )
        if f.camera_id in refused:
            raise FieldProblem(
                422,
                f"{where}.camera_id",
                f"{refused[f.camera_id]}; calibrate and pose it before sending its frames",
            )
        key = (f.camera_id, f.t)
        if key in detected:
            raise FieldProblem(
                422,
                where,
                f"camera {f.camera_id} has detections at t = {f.t} in this batch: a frame is "
                "either empty or has detections; drop it from empty_frames",
            )
        if key in seen:
            raise FieldProblem(
                422, where, f"camera {f.camera_id} at t = {f.t} is listed twice in empty_frames"
            )
        seen.add(key)


def _check_labels(
    obs: list[Observation], space_of: dict[int, int | None], live: LiveTargets
) -> None:
    """Refuse a batch whose labels would make a space hold more than MAX_LIVE_LABELS live
    labelled targets: 422 when the batch alone has more, 429 (retry once some have retired)
    when the live ones and the batch's new ones together have."""
    labels: dict[int | None, set[str]] = {}
    for o in obs:
        if o.target is not None:
            labels.setdefault(space_of.get(o.camera_id), set()).add(o.target)
    for space_id, wanted in labels.items():
        if len(wanted) > MAX_LIVE_LABELS:
            raise FieldProblem(
                422,
                "observations",
                f"the batch labels {len(wanted)} distinct targets in space {space_id}; a space "
                f"follows at most {MAX_LIVE_LABELS} labelled targets at once",
            )
        current = live.live_labels(space_id)
        total = len(current | wanted)
        if total > MAX_LIVE_LABELS:
            raise HTTPException(
                status.HTTP_429_TOO_MANY_REQUESTS,
                detail=f"space {space_id} follows {len(current)} labelled targets and the batch "
                f"adds {total - len(current)} more, over the limit of {MAX_LIVE_LABELS}; a "
                f"label retires {LABEL_RETIRES_AFTER_S} s after its last detection",
                headers={"Retry-After": str(LABEL_RETIRES_AFTER_S)},
            )
