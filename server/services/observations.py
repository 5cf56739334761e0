"""What POST /observations measures in a batch of detections before the tracker gets them.

* `camera_rows(...)`: the registry's facts about the batch's cameras (space, score threshold,
  image size).
* `drop_unseen_robots(...)`: "robot" detections of cameras whose space has no robot dropped.
* `measure(...)`: every observation's pixel and covariance: the pixel sent, or a box's foot
  point (core.localization.box_foot) moved to the body's axis (core.localization.foot_on_axis);
  which boxes are kept (scored at or over their camera's threshold) and which give a floor
  position (not cut at the bottom).
* `locate_labelled(...)`: each labelled (target, t, height) located at once by maximum
  likelihood on the plane (core.localization.locate_groups).
* `detections_in(...)`: the kept observations as the tracker's detections.

A batch that names something wrong raises `ObservationRefused` with the field at fault.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import select
from sqlalchemy.orm import Session

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
from server.db.models import Camera, Robot
from server.schemas.localization import EmptyFrame, Observation
from server.services.tracking import DetectionIn, TrackingService

_STATUS = {
    PointStatus.OK: "ok",
    PointStatus.TOO_FEW_CAMERAS: "too_few_cameras",
    PointStatus.DEGENERATE: "degenerate",
    PointStatus.BEHIND_CAMERA: "behind_camera",
}

# A box may reach past the image by this fraction of its size (a detector's box around a
# person at the edge); further, it is not a box of this camera.
_BOX_MARGIN = 0.25


class ObservationRefused(Exception):
    """A batch the service refuses (HTTP 422): the request `field` at fault and the reason."""

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(reason)
        self.field = field


@dataclass(frozen=True)
class CameraRow:
    """What the measurement needs of a camera's registry row."""

    space_id: int | None
    score_threshold: float
    width: int
    height: int


def camera_rows(session: Session, camera_ids: list[int]) -> dict[int, CameraRow]:
    """Return the registry rows of the cameras `camera_ids` (those that exist), by id."""
    rows = session.execute(
        select(
            Camera.id, Camera.space_id, Camera.score_threshold, Camera.width, Camera.height
        ).where(Camera.id.in_(camera_ids))
    )
    return {r[0]: CameraRow(r[1], float(r[2]), int(r[3]), int(r[4])) for r in rows}


def robotless(session: Session, space_of: dict[int, int | None]) -> set[int]:
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


def drop_unseen_robots(
    session: Session,
    obs: list[Observation],
    empty: list[EmptyFrame],
    space_of: dict[int, int | None],
) -> tuple[list[Observation], list[EmptyFrame], list[Observation]]:
    """Return (observations, empty frames, dropped observations) once the "robot" detections of
    cameras whose space has no robot (`robotless`) are dropped: a space with no registered
    robot has no robot to see, and a "robot" detection there is a red thing mistaken for its
    marker (spec 08, "Real footage"). Dropping a kind is filtering, not association; a frame
    left with nothing becomes an empty frame for the tracker."""
    no_robot = robotless(session, space_of)
    ignored = [o for o in obs if o.kind == "robot" and o.camera_id in no_robot]
    if ignored:
        obs = [o for o in obs if not (o.kind == "robot" and o.camera_id in no_robot)]
        left = {(o.camera_id, o.t) for o in obs}
        emptied = {(o.camera_id, o.t) for o in ignored} - left
        empty = [*empty, *(EmptyFrame(camera_id=c, t=t) for c, t in sorted(emptied))]
    return obs, empty, ignored


@dataclass(frozen=True)
class Measured:
    """Every observation's measured pixel (N, 2) and covariance (N, 2, 2); `keep` (N,): not a
    box scored under its camera's threshold; `tracked` (N,): gives a floor position (not a box
    with a cut bottom)."""

    pixel: NDArray[np.float64]
    cov: NDArray[np.float64]
    keep: NDArray[np.bool_]
    tracked: NDArray[np.bool_]


def _cov(o: Observation) -> tuple[tuple[float, float], tuple[float, float]]:
    if o.cov is not None:
        (a, b), (c, d) = o.cov
        return ((a, b), (c, d))
    s2 = (o.sigma_px or 1.0) ** 2
    return ((s2, 0.0), (0.0, s2))


def measure(
    obs: Sequence[Observation],
    rows: dict[int, CameraRow],
    cameras: dict[int, NetworkCamera],
    space_of: dict[int, int | None],
    tracking: TrackingService | None,
) -> Measured:
    """Return the measured pixels of the observations: their pixels, or their boxes' feet
    (core.localization.box_foot) moved to the body's axis by the camera's geometry and the
    camera's space's floor plan (core.localization.foot_on_axis). Raises ObservationRefused
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
        return Measured(pixel, cov, keep, tracked)
    boxes = np.array([obs[i].box for i in boxed], dtype=np.float64)
    size = np.array([(rows[obs[i].camera_id].width, rows[obs[i].camera_id].height) for i in boxed])
    lo, hi = -_BOX_MARGIN * size, (1.0 + _BOX_MARGIN) * size
    outside = np.any(boxes[:, :2] < lo, axis=1) | np.any(boxes[:, 2:] > hi, axis=1)
    if np.any(outside):
        k = int(np.argmax(outside))
        w, h = size[k]
        raise ObservationRefused(
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
    return Measured(pixel, cov, keep, tracked)


def locate_labelled(
    every: Sequence[Observation],
    index: list[int],
    cameras: dict[int, NetworkCamera],
    measured: Measured,
) -> list[dict[str, Any]]:
    """Return the ML floor position of each labelled (target, t, height) group of the
    observations `every[i]` for i in `index` (core.localization.locate_groups), as the answer
    lists them. Raises ObservationRefused when a camera sees a group twice."""
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
        raise ObservationRefused(
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


def detections_in(obs: Sequence[Observation], m: Measured) -> list[DetectionIn]:
    """Return the kept observations (`m.keep`) as the tracker's detections, each with its
    measured pixel and covariance (a box without a kind is a person's)."""
    return [
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
            appearance=None if o.appearance is None else tuple(o.appearance),
            tracked=bool(m.tracked[i]),
        )
        for i, o in enumerate(obs)
        if m.keep[i]
    ]
