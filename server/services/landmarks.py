"""Landmarks in the service: a registry row's record and artwork, detections as JSON, and the
space's semantic and navigation maps kept in the database (core.landmarks.maps does the maths).

The maps are stored, not held in memory: every update loads the rows it touches into a
core map, lets the core fuse or rebuild, and writes the result back in the same transaction, so
a restart (or another worker) sees the same maps.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any, TypeVar

import numpy as np
from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from core.errors import InvalidInput
from core.landmarks import (
    LandmarkDetection,
    NavigationMap,
    ObjectMark,
    PayloadError,
    Record,
    SemanticMap,
    Signpost,
    decode_payload,
    detection_in_world,
    encode_payload,
)
from core.landmarks.artwork import Artwork, make_artwork
from core.landmarks.maps import SemanticObject as CoreObject
from server.db.models import Landmark, NavigationEdge, NavigationPlace, SemanticObject
from server.schemas.landmarks import Detection, MapChange, MapUpdate, PoseHypothesisOut

# Registry kinds whose payload is ours (spec 04); others (ArUco, AprilTag, ...) print elsewhere.
QR_KIND = "qr"


class LandmarkUnusable(Exception):
    """A registry landmark that cannot be printed or mapped: the field and why."""

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(reason)
        self.field = field
        self.reason = reason


def landmark_record(landmark: Landmark) -> Record:
    """Return the decoded payload (ObjectMark or Signpost) of a registry landmark; raise
    LandmarkUnusable naming why when it is not a QR landmark or its payload is not ours."""
    if landmark.kind != QR_KIND:
        raise LandmarkUnusable(
            "kind",
            f"landmark {landmark.id} is of kind {landmark.kind!r}; only {QR_KIND!r} landmarks "
            "carry an object-mark or signpost payload",
        )
    try:
        return decode_payload(landmark.payload)
    except PayloadError as exc:
        raise LandmarkUnusable(
            "payload",
            f"landmark {landmark.id}'s payload is not a landmark payload ({exc.reason}): {exc}",
        ) from None


def landmark_artwork(landmark: Landmark) -> Artwork:
    """Return the artwork of a registry landmark at its size_m (the frame's outer side or the
    outer ring's diameter); LandmarkUnusable when it cannot be drawn."""
    record = landmark_record(landmark)
    try:
        return make_artwork(record, size=landmark.size_m)
    except InvalidInput as exc:
        raise LandmarkUnusable("size_m", f"landmark {landmark.id}: {exc}") from None


def record_json(record: Record | None) -> dict[str, Any] | None:
    """Return a decoded payload as JSON (its fields and its kind), None for None."""
    if record is None:
        return None
    body: dict[str, Any] = {"kind": record.kind}
    for key, value in dataclasses.asdict(record).items():
        body[key] = list(value) if isinstance(value, tuple) else value
    return body


def detection_read(det: LandmarkDetection) -> Detection:
    """Return one detection as the API shows it: kind, outline (N, 2) px, T_cam_mark, cov
    (rvec then t), position and normal in the camera frame, record or reason, raw text,
    diagnostics, and whether the image decides the pose with the poses it leaves possible (a
    signpost's two, each with its own covariance and probability; when undecided, cov covers
    both)."""
    return Detection(
        kind=det.kind,
        outline=np.asarray(det.outline, float).tolist(),
        T_cam_mark=det.T_cam_mark.tolist(),
        cov=det.cov.tolist(),
        position=det.position.tolist(),
        normal=det.normal.tolist(),
        distance_m=float(np.linalg.norm(det.position)),
        record=record_json(det.record),
        reason=det.reason,
        text=det.text,
        orientation_known=bool(det.orientation_known),
        rms_px=float(det.rms),
        decided=bool(det.decided),
        hypotheses=[
            PoseHypothesisOut(
                T_cam_mark=h.T.tolist(), cov=h.cov.tolist(), probability=h.probability
            )
            for h in det.hypotheses
        ],
    )


# The maps


@dataclasses.dataclass(frozen=True)
class MapObservation:
    """A read landmark to enter the maps: its record, its pose in the world (4, 4) and the
    (6, 6) covariance of (rotation perturbation, position), the time it was read (Unix s)."""

    record: Record
    T_world_mark: np.ndarray
    cov: np.ndarray
    time: float


def located_observation(
    payload: str,
    T_cam_mark: Any,
    cov: Any,
    T_world_camera: Any,
    when: float | None,
) -> MapObservation:
    """Return the map observation of a detection (payload text, T_cam_mark, cov of (rvec, t))
    made by a camera at T_world_camera. Raises PayloadError or InvalidInput naming what is
    wrong."""
    record = decode_payload(payload)
    det = LandmarkDetection(
        kind=record.kind,
        outline=np.zeros((0, 2)),
        T_cam_mark=np.asarray(T_cam_mark, float),
        cov=np.asarray(cov, float),
        record=record,
        reason=None,
    )
    T, C = detection_in_world(det, T_world_camera)
    # A home is tens of metres across: farther is a wrong pose, and huge numbers would not
    # survive the maps' fusion (nor JSON) as finite ones.
    if not (np.all(np.isfinite(T)) and np.all(np.isfinite(C))) or np.abs(T[:3, 3]).max() > 1e4:
        raise InvalidInput(
            f"the landmark's world position {T[:3, 3].tolist()} is not within 10 km of the "
            "origin; check T_cam_mark and the camera's pose"
        )
    return MapObservation(record, T, C, time.time() if when is None else float(when))


def _core_object(row: SemanticObject) -> CoreObject:
    record = decode_payload(row.payload)
    assert isinstance(record, ObjectMark)
    return CoreObject(
        row.mark_id,
        row.object_class,
        row.name,
        row.room,
        np.asarray(row.T_world_mark, float),
        np.asarray(row.cov, float),
        row.last_seen,
        row.reads,
        record,
    )


def semantic_features(session: Session, space_id: int) -> dict[str, Any]:
    """Return the space's semantic map as a GeoJSON-like FeatureCollection."""
    rows = session.scalars(
        select(SemanticObject)
        .where(SemanticObject.space_id == space_id)
        .order_by(SemanticObject.mark_id)
    ).all()
    return {"type": "FeatureCollection", "features": [_core_object(r).to_feature() for r in rows]}


def navigation_map(session: Session, space_id: int) -> NavigationMap:
    """Return the space's navigation map rebuilt from its stored places."""
    nav = NavigationMap()
    rows = session.scalars(
        select(NavigationPlace)
        .where(NavigationPlace.space_id == space_id)
        .order_by(NavigationPlace.mark_id)
    ).all()
    for row in rows:
        record = decode_payload(row.payload)
        assert isinstance(record, Signpost)
        nav.observe(record)
    return nav


_Marked = TypeVar("_Marked", SemanticObject, NavigationPlace)


def _stored_mark(
    session: Session, model: type[_Marked], space_id: int, mark_id: int
) -> _Marked | None:
    """Return the row of `model` (an object or a place of the map) of mark `mark_id` in space
    `space_id`, None when the map has none yet."""
    return session.scalar(select(model).where(model.space_id == space_id, model.mark_id == mark_id))


def _observe_object(session: Session, space_id: int, obs: MapObservation) -> str:
    record = obs.record
    assert isinstance(record, ObjectMark)
    row = _stored_mark(session, SemanticObject, space_id, record.id)
    semantic = SemanticMap()
    if row is not None:
        # The stored entry enters as one read at its fused pose; the new read fuses into it
        # (an information-weighted mean: the count of earlier reads does not weigh in).
        semantic.observe(
            decode_payload(row.payload),  # type: ignore[arg-type]
            row.T_world_mark,
            row.cov,
            row.last_seen,
        )
    fused = semantic.observe(record, obs.T_world_mark, obs.cov, obs.time)
    reads = 1 if row is None else row.reads + 1
    fused = dataclasses.replace(fused, reads=reads)
    values = {
        "object_class": fused.object_class,
        "name": fused.name,
        "room": fused.room,
        "T_world_mark": fused.T_world_mark.tolist(),
        "cov": fused.cov.tolist(),
        "last_seen": fused.last_seen,
        "reads": reads,
        "confidence": fused.confidence,
        "payload": encode_payload(record),
    }
    if row is None:
        session.add(SemanticObject(space_id=space_id, mark_id=record.id, **values))
        return "added"
    for key, value in values.items():
        setattr(row, key, value)
    return "updated"


def _observe_place(session: Session, space_id: int, obs: MapObservation) -> str:
    record = obs.record
    assert isinstance(record, Signpost)
    row = _stored_mark(session, NavigationPlace, space_id, record.id)
    values = {
        "name": record.name,
        "room": record.room,
        "pose": list(record.pose),
        "neighbours": list(record.neighbours),
        "payload": encode_payload(record),
    }
    if row is None:
        session.add(
            NavigationPlace(
                space_id=space_id, mark_id=record.id, last_seen=obs.time, reads=1, **values
            )
        )
        return "added"
    for key, value in values.items():
        setattr(row, key, value)
    row.last_seen = max(row.last_seen, obs.time)
    row.reads += 1
    return "updated"


def _store_edges(session: Session, space_id: int) -> int:
    nav = navigation_map(session, space_id)
    session.execute(delete(NavigationEdge).where(NavigationEdge.space_id == space_id))
    edges = 0
    for a, b, data in nav.graph.edges(data=True):
        lo, hi = sorted((int(a), int(b)))
        session.add(
            NavigationEdge(
                space_id=space_id,
                from_mark=lo,
                to_mark=hi,
                length_m=float(data["weight"]),
                via=str(data["via"]),
            )
        )
        edges += 1
    return edges


def observe(session: Session, space_id: int, observations: list[MapObservation]) -> MapUpdate:
    """Enter read landmarks into the space's maps (objects: fused, never duplicated; signposts:
    places, edges rebuilt) and commit; return what changed per landmark and the edge count."""
    changes: list[MapChange] = []
    places = False
    for obs in observations:
        if isinstance(obs.record, ObjectMark):
            what = _observe_object(session, space_id, obs)
            changes.append(MapChange(map="semantic", mark_id=obs.record.id, change=what))
        else:
            what = _observe_place(session, space_id, obs)
            places = True
            changes.append(MapChange(map="navigation", mark_id=obs.record.id, change=what))
        session.flush()
    edges = _store_edges(session, space_id) if places else None
    session.commit()
    return MapUpdate(space_id=space_id, changes=changes, navigation_edges=edges)
