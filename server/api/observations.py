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
from dataclasses import dataclass
from typing import Annotated

import numpy as np
from fastapi import APIRouter, Depends, HTTPException, status
from fastapi.responses import JSONResponse
from sqlalchemy import select

from core.localization import (
    DuplicateView,
    FootMeasurement,
    NetworkCamera,
    PointStatus,
    box_foot,
    cut_mask,
    foot_on_axis,
    locate_groups,
)
from server.api.deps import SessionDep, get_live_targets, get_tracking, require_write
from server.api.errors import PROBLEM_RESPONSES, FieldProblem
from server.api.server_time import SERVER_TIME_HEADER
from server.db.models import Camera, Robot
from server.schemas.localization import EmptyFrame, Observation, ObservationBatch, PositionBatch
from server.services.auth import Principal
from server.services.targets import LiveTargets
from server.services.tracking import DetectionIn, TrackingService
from server.services.twin import registry_cameras

router = APIRouter(tags=["localization"], responses=PROBLEM_RESPONSES)

# Live labelled targets a space may hold: every distinct label is a live target until it has
# been silent for the tracker's labelled_end_after (60 s), and each is in every stream tick. A
# home labels a few bodies; 40,000 labels made each tick 7.8 MB.
MAX_LIVE_LABELS = 256
# How long a silent labelled target stays live (core TrackerConfig.labelled_end_after), s.
LABEL_RETIRES_AFTER_S = 60

_STATUS = {
    PointStatus.OK: "ok",
    PointStatus.TOO_FEW_CAMERAS: "too_few_cameras",
    PointStatus.DEGENERATE: "degenerate",
    PointStatus.BEHIND_CAMERA: "behind_camera",
}


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
    rows = _camera_rows(session, camera_ids)
    space_of = {cid: row.space_id for cid, row in rows.items()}
    # A space with no registered robot has no robot to see: a "robot" detection there is a red
    # thing mistaken for its marker (spec 08, "Real footage"). Dropping a kind is filtering,
    # not association; a frame left with nothing is an empty frame to the tracker.
    robotless = _robotless(session, space_of)
    ignored = [o for o in obs if o.kind == "robot" and o.camera_id in robotless]
    if ignored:
        obs = [o for o in obs if not (o.kind == "robot" and o.camera_id in robotless)]
        left = {(o.camera_id, o.t) for o in obs}
        emptied = {(o.camera_id, o.t) for o in ignored} - left
        empty = [*empty, *(EmptyFrame(camera_id=c, t=t) for c, t in sorted(emptied))]
    m = _measure(obs, rows, cameras, space_of, tracking)
    if live is not None:
        _check_labels(obs, space_of, live)
    labelled = [i for i, o in enumerate(obs) if o.target is not None and m.keep[i] and m.tracked[i]]
    positions = _locate_labelled(obs, labelled, cameras, m) if labelled else []
    detections = [
        DetectionIn(
            camera_id=o.camera_id,
            t=o.t,
            pixel=(float(m.pixel[i, 0]), float(m.pixel[i, 1])),
            cov=((m.cov[i, 0, 0], m.cov[i, 0, 1]), (m.cov[i, 1, 0], m.cov[i, 1, 1])),
            kind=o.kind or ("person" if o.box is not None else "unknown"),
            height=o.height,
            label=o.target,
            box=None if o.box is None else (o.box[0], o.box[1], o.box[2], o.box[3]),
            score=o.score,
            cut=None if o.box is None else tuple(o.cut or ()),
            tracked=bool(m.tracked[i]),
        )
        for i, o in enumerate(obs)
        if m.keep[i]
    ]
    if tracking is not None:
        marks = [(f.camera_id, f.t) for f in empty]
        result = tracking.ingest(session, detections, space_of, empty=marks)
        stored, frames, late = result.stored, result.frames, result.late
    else:  # pragma: no cover - the app always has its tracking service once started
        stored, frames, late = 0, 0, 0
    body = {
        "stored": stored,
        "frames": frames,
        "late": late,
        "ignored": len(ignored),
        "positions": positions,
    }
    # The service's clock to the microsecond: a camera node measures its clock offset by it
    # (the Date header has whole seconds, refreshed late when the service is loaded).
    return JSONResponse(body, headers={SERVER_TIME_HEADER: f"{time.time():.6f}"})


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


def _check_labels(obs, space_of: dict[int, int | None], live: LiveTargets) -> None:
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


def _cov(o) -> tuple[tuple[float, float], tuple[float, float]]:
    if o.cov is not None:
        (a, b), (c, d) = o.cov
        return ((a, b), (c, d))
    s2 = (o.sigma_px or 1.0) ** 2
    return ((s2, 0.0), (0.0, s2))


@dataclass(frozen=True)
class _CameraRow:
    space_id: int | None
    score_threshold: float
    width: int
    height: int


def _camera_rows(session, camera_ids: list[int]) -> dict[int, _CameraRow]:
    rows = session.execute(
        select(
            Camera.id, Camera.space_id, Camera.score_threshold, Camera.width, Camera.height
        ).where(Camera.id.in_(camera_ids))
    )
    return {r[0]: _CameraRow(r[1], float(r[2]), int(r[3]), int(r[4])) for r in rows}


# A box may reach past the image by this fraction of its size (a detector's box around a
# person at the edge); further, it is not a box of this camera.
_BOX_MARGIN = 0.25


@dataclass(frozen=True)
class _Measured:
    """Every observation's measured pixel (N, 2) and covariance (N, 2, 2); `keep`: not a box
    scored under its camera's threshold; `tracked`: gives a floor position (not a box with a
    cut bottom)."""

    pixel: np.ndarray
    cov: np.ndarray
    keep: np.ndarray
    tracked: np.ndarray


def _measure(
    obs: list[Observation],
    rows: dict[int, _CameraRow],
    cameras: dict[int, NetworkCamera],
    space_of: dict[int, int | None],
    tracking: TrackingService | None,
) -> _Measured:
    """Return the measured pixels of the observations: their pixels, or their boxes' feet
    (core.localization.box_foot) moved to the body's axis by the camera's geometry and the
    camera's space's floor plan (core.localization.foot_on_axis). Raises FieldProblem 422
    naming a box outside its camera's image (by more than _BOX_MARGIN of the image's size)."""
    n = len(obs)
    pixel = np.zeros((n, 2))
    cov = np.zeros((n, 2, 2))
    keep = np.ones(n, dtype=bool)
    tracked = np.ones(n, dtype=bool)
    boxed = [i for i, o in enumerate(obs) if o.box is not None]
    for i, o in enumerate(obs):
        if o.pixel is not None:
            pixel[i] = o.pixel
            cov[i] = _cov(o)
    if not boxed:
        return _Measured(pixel, cov, keep, tracked)
    boxes = np.array([obs[i].box for i in boxed], dtype=np.float64)
    size = np.array([(rows[obs[i].camera_id].width, rows[obs[i].camera_id].height) for i in boxed])
    lo, hi = -_BOX_MARGIN * size, (1.0 + _BOX_MARGIN) * size
    outside = np.any(boxes[:, :2] < lo, axis=1) | np.any(boxes[:, 2:] > hi, axis=1)
    if np.any(outside):
        k = int(np.argmax(outside))
        w, h = size[k]
        raise FieldProblem(
            422,
            f"observations.{boxed[k]}.box",
            f"box {boxes[k].tolist()} is outside camera {obs[boxed[k]].camera_id}'s "
            f"{w}x{h} image; a box is in the camera's distorted pixels",
        )
    cut = cut_mask(obs[i].cut or () for i in boxed)
    foot = box_foot(boxes, cut)
    on = np.array([obs[i].camera_id for i in boxed])
    for cid in np.unique(on).tolist():
        mine = np.flatnonzero(on == cid)
        plan = None if tracking is None else tracking.floor_plan(space_of.get(cid))
        axis = foot_on_axis(
            boxes[mine],
            FootMeasurement(foot.pixel[mine], foot.cov[mine], foot.measured[mine]),
            cameras[cid],
            cut=cut[mine],
            occluders=plan,
        )
        at = [boxed[k] for k in mine]
        pixel[at], cov[at], tracked[at] = axis.pixel, axis.cov, axis.measured
    threshold = np.array([rows[obs[i].camera_id].score_threshold for i in boxed])
    score = np.array([1.0 if obs[i].score is None else obs[i].score for i in boxed])
    keep[boxed] = score >= threshold
    return _Measured(pixel, cov, keep, tracked)


def _robotless(session, space_of: dict[int, int | None]) -> set[int]:
    """Return the cameras (ids of `space_of`) whose space has no robot in the registry (a
    camera in no space: when no robot is in no space either)."""
    spaces = set(space_of.values())
    wanted = [s for s in spaces if s is not None]
    held: set[int | None] = set()
    if wanted:
        held |= set(
            session.scalars(select(Robot.space_id).where(Robot.space_id.in_(wanted)).distinct())
        )
    if None in spaces:
        stmt = select(Robot.id).where(Robot.space_id.is_(None)).limit(1)
        if session.scalars(stmt).first() is not None:
            held.add(None)
    return {cid for cid, sid in space_of.items() if sid not in held}


def _locate_labelled(every, index: list[int], cameras, measured: _Measured) -> list[dict]:
    """Return the ML floor position of each labelled (target, t, height) group of the
    observations `every[i]` for i in `index` (core.localization.locate_groups)."""
    obs = [every[i] for i in index]
    camera_ids = sorted({o.camera_id for o in obs})
    column = {cid: k for k, cid in enumerate(camera_ids)}
    groups: dict[tuple[str | None, float, float], int] = {}
    group = [groups.setdefault((o.target, o.t, o.height), len(groups)) for o in obs]
    try:
        found = locate_groups(
            [cameras[cid] for cid in camera_ids],
            [column[o.camera_id] for o in obs],
            group,
            [key[2] for key in groups],
            measured.pixel[index],
            measured.cov[index],
        )
    except DuplicateView as exc:
        o = obs[exc.index]
        raise FieldProblem(
            422,
            f"observations.{index[exc.index]}",
            f"camera {o.camera_id} has more than one detection of target "
            f"{o.target!r} at t = {o.t}; send one per camera, target and time",
        ) from exc
    positions = []
    for b, (target, t, _) in enumerate(groups):
        ok = found.status[b] == PointStatus.OK
        positions.append(
            {
                "target": target,
                "t": t,
                "xy": found.xy[b].tolist() if ok else None,
                "cov": found.cov[b].tolist() if ok else None,
                "n_cameras": int(found.n_cameras[b]),
                "estimator": "ml",
                "status": _STATUS[PointStatus(int(found.status[b]))],
            }
        )
    return positions
