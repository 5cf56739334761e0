"""A time range of a space as MCAP with Foxglove's well-known schemas, so a session opens in
Foxglove (and converts to Rerun).

Schemas are `foxglove.*` JSON schemas (schema encoding `jsonschema`, message encoding `json`;
times as {sec, nsec}, bytes as base64), one channel per topic:

* `/cameras/{name}/calibration` foxglove.CameraCalibration: each calibrated camera's K and
  distortion (plumb_bob: k1, k2, p1, p2, k3), once at the range's start.
* `/tf` foxglove.FrameTransform: each posed camera's frame in `world` (at the range's start),
  and each robot target's pose (its tracked floor position; the tracker does not estimate a
  heading, so the rotation is the identity) at every track point.
* `/cameras/{name}/detections` foxglove.ImageAnnotations: per camera frame, a circle per
  detection (diameter: 3 standard deviations each side along the covariance's major axis) and
  its kind as text, in the camera's image (distorted pixels, as detected).
* `/targets/{label}` foxglove.PoseInFrame: every stored track point of each target, in `world`
  (floor position, z = 0).
* `/cameras/{name}/image` foxglove.CompressedImage: the newest frame of each twin camera when
  it lies in the range (the service keeps no other images: a camera node's recording keeps
  them).

Rows are read in time order in pages and written as they come; the file is streamed in chunks
(`mcap_stream`), never held whole. Messages are in log-time order across topics.
"""

from __future__ import annotations

import base64
import heapq
import json
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from mcap.writer import CompressionType, Writer
from sqlalchemy import select
from sqlalchemy.orm import Session

from core.geometry.rotations import matrix_to_quaternion
from server.db.models import Camera, Detection, Target, TrackPoint

WORLD = "world"
_PAGE = 2000
# Bytes written before they are handed to the response.
_FLUSH_BYTES = 256 * 1024
_KIND_RGBA = {
    "robot": (0.86, 0.08, 0.12, 1.0),
    "person": (0.1, 0.45, 0.9, 1.0),
    "unknown": (0.6, 0.6, 0.6, 1.0),
}

# -- Foxglove's well-known schemas (JSON schema) ------------------------------------------------

_NUMBER = {"type": "number"}
_TIME = {
    "type": "object",
    "title": "time",
    "properties": {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
    },
}
_VECTOR3 = {
    "type": "object",
    "title": "foxglove.Vector3",
    "properties": {"x": _NUMBER, "y": _NUMBER, "z": _NUMBER},
}
_QUATERNION = {
    "type": "object",
    "title": "foxglove.Quaternion",
    "properties": {"x": _NUMBER, "y": _NUMBER, "z": _NUMBER, "w": _NUMBER},
}
_POSE = {
    "type": "object",
    "title": "foxglove.Pose",
    "properties": {"position": _VECTOR3, "orientation": _QUATERNION},
}
_POINT2 = {"type": "object", "title": "foxglove.Point2", "properties": {"x": _NUMBER, "y": _NUMBER}}
_COLOR = {
    "type": "object",
    "title": "foxglove.Color",
    "properties": {"r": _NUMBER, "g": _NUMBER, "b": _NUMBER, "a": _NUMBER},
}
_NUMBERS = {"type": "array", "items": _NUMBER}


def _schema(title: str, properties: dict[str, Any]) -> dict[str, Any]:
    return {"title": title, "type": "object", "properties": properties}


SCHEMAS: dict[str, dict[str, Any]] = {
    "foxglove.CameraCalibration": _schema(
        "foxglove.CameraCalibration",
        {
            "timestamp": _TIME,
            "frame_id": {"type": "string"},
            "width": {"type": "integer", "minimum": 0},
            "height": {"type": "integer", "minimum": 0},
            "distortion_model": {"type": "string"},
            "D": _NUMBERS,
            "K": {**_NUMBERS, "minItems": 9, "maxItems": 9},
            "R": {**_NUMBERS, "minItems": 9, "maxItems": 9},
            "P": {**_NUMBERS, "minItems": 12, "maxItems": 12},
        },
    ),
    "foxglove.FrameTransform": _schema(
        "foxglove.FrameTransform",
        {
            "timestamp": _TIME,
            "parent_frame_id": {"type": "string"},
            "child_frame_id": {"type": "string"},
            "translation": _VECTOR3,
            "rotation": _QUATERNION,
        },
    ),
    "foxglove.PoseInFrame": _schema(
        "foxglove.PoseInFrame",
        {"timestamp": _TIME, "frame_id": {"type": "string"}, "pose": _POSE},
    ),
    "foxglove.CompressedImage": _schema(
        "foxglove.CompressedImage",
        {
            "timestamp": _TIME,
            "frame_id": {"type": "string"},
            "data": {"type": "string", "contentEncoding": "base64"},
            "format": {"type": "string"},
        },
    ),
    "foxglove.ImageAnnotations": _schema(
        "foxglove.ImageAnnotations",
        {
            "circles": {
                "type": "array",
                "items": _schema(
                    "foxglove.CircleAnnotation",
                    {
                        "timestamp": _TIME,
                        "position": _POINT2,
                        "diameter": _NUMBER,
                        "thickness": _NUMBER,
                        "fill_color": _COLOR,
                        "outline_color": _COLOR,
                    },
                ),
            },
            "points": {
                "type": "array",
                "items": _schema(
                    "foxglove.PointsAnnotation",
                    {
                        "timestamp": _TIME,
                        "type": {"type": "integer", "minimum": 0, "maximum": 4},
                        "points": {"type": "array", "items": _POINT2},
                        "outline_color": _COLOR,
                        "outline_colors": {"type": "array", "items": _COLOR},
                        "fill_color": _COLOR,
                        "thickness": _NUMBER,
                    },
                ),
            },
            "texts": {
                "type": "array",
                "items": _schema(
                    "foxglove.TextAnnotation",
                    {
                        "timestamp": _TIME,
                        "position": _POINT2,
                        "text": {"type": "string"},
                        "font_size": _NUMBER,
                        "text_color": _COLOR,
                        "background_color": _COLOR,
                    },
                ),
            },
        },
    ),
}


# -- messages -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LatestImage:
    """A camera's newest frame: camera id, capture time (Unix s) and its JPEG bytes."""

    camera_id: int
    t: float
    jpeg: bytes


@dataclass(frozen=True)
class Message:
    """One MCAP message: log time (ns), topic, schema name and the JSON payload."""

    log_time: int
    topic: str
    schema: str
    payload: dict[str, Any]


def stamp(t: float) -> dict[str, int]:
    """Return Unix seconds `t` as Foxglove's time {sec, nsec}."""
    ns = _ns(t)
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _ns(t: float) -> int:
    return round(float(t) * 1e9)


def _rgba(kind: str) -> dict[str, float]:
    r, g, b, a = _KIND_RGBA.get(kind, _KIND_RGBA["unknown"])
    return {"r": r, "g": g, "b": b, "a": a}


def camera_frame(name: str) -> str:
    """Return the coordinate frame id of the camera called `name`."""
    return f"cameras/{name}"


def _camera_messages(cameras: list[Camera], since: float) -> list[Message]:
    out = []
    for cam in cameras:
        frame = camera_frame(cam.name)
        if cam.K is not None:
            K = np.asarray(cam.K, dtype=np.float64)
            P = np.hstack([K, np.zeros((3, 1))])
            out.append(
                Message(
                    _ns(since),
                    f"/cameras/{cam.name}/calibration",
                    "foxglove.CameraCalibration",
                    {
                        "timestamp": stamp(since),
                        "frame_id": frame,
                        "width": cam.width,
                        "height": cam.height,
                        "distortion_model": "plumb_bob",
                        "D": [float(v) for v in (cam.dist or [0.0] * 5)],
                        "K": K.ravel().tolist(),
                        "R": np.eye(3).ravel().tolist(),
                        "P": P.ravel().tolist(),
                    },
                )
            )
        if cam.T_world_camera is not None:
            T = np.asarray(cam.T_world_camera, dtype=np.float64)
            x, y, z, w = matrix_to_quaternion(T[:3, :3])
            out.append(
                Message(
                    _ns(since),
                    "/tf",
                    "foxglove.FrameTransform",
                    {
                        "timestamp": stamp(since),
                        "parent_frame_id": WORLD,
                        "child_frame_id": frame,
                        "translation": dict(zip("xyz", T[:3, 3].tolist(), strict=True)),
                        "rotation": {"x": x, "y": y, "z": z, "w": w},
                    },
                )
            )
    return out


def _annotations(name: str, t: float, rows: list[Detection]) -> Message:
    circles, texts = [], []
    for d in rows:
        cov = np.array([[d.cxx, d.cxy], [d.cxy, d.cyy]])
        major = float(np.sqrt(max(np.linalg.eigvalsh(cov)[-1], 0.0)))
        colour = _rgba(d.kind)
        position = {"x": d.u, "y": d.v}
        circles.append(
            {
                "timestamp": stamp(t),
                "position": position,
                "diameter": max(6.0 * major, 4.0),  # 3 sigma each side, at least 4 px
                "thickness": 2.0,
                "fill_color": {**colour, "a": 0.0},
                "outline_color": colour,
            }
        )
        texts.append(
            {
                "timestamp": stamp(t),
                "position": {"x": d.u + 6.0, "y": d.v - 6.0},
                "text": d.kind if d.label is None else f"{d.kind} {d.label}",
                "font_size": 12.0,
                "text_color": colour,
                "background_color": {"r": 0.0, "g": 0.0, "b": 0.0, "a": 0.5},
            }
        )
    return Message(
        _ns(t),
        f"/cameras/{name}/detections",
        "foxglove.ImageAnnotations",
        {"circles": circles, "points": [], "texts": texts},
    )


def _detection_messages(
    session: Session, space_id: int, since: float, until: float, names: dict[int, str]
) -> Iterator[Message]:
    """Yield one ImageAnnotations per camera frame (camera, capture time), in time order."""
    stmt = (
        select(Detection)
        .where(Detection.space_id == space_id, Detection.t >= since, Detection.t <= until)
        .order_by(Detection.t, Detection.camera_id, Detection.id)
        .execution_options(yield_per=_PAGE)
    )
    group: list[Detection] = []
    for d in session.scalars(stmt):
        if group and (d.camera_id, d.t) != (group[0].camera_id, group[0].t):
            yield _annotations(
                names.get(group[0].camera_id, str(group[0].camera_id)), group[0].t, group
            )
            group = []
        group.append(d)
    if group:
        yield _annotations(
            names.get(group[0].camera_id, str(group[0].camera_id)), group[0].t, group
        )


def _track_messages(
    session: Session, space_id: int, since: float, until: float
) -> Iterator[Message]:
    """Yield a PoseInFrame per track point (and a FrameTransform per robot's), in time order."""
    stmt = (
        select(TrackPoint.t, TrackPoint.x, TrackPoint.y, Target.label, Target.kind)
        .join(Target, Target.id == TrackPoint.target_id)
        .where(Target.space_id == space_id, TrackPoint.t >= since, TrackPoint.t <= until)
        .order_by(TrackPoint.t, TrackPoint.id)
        .execution_options(yield_per=_PAGE)
    )
    identity = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
    for t, x, y, label, kind in session.execute(stmt):
        position = {"x": x, "y": y, "z": 0.0}
        yield Message(
            _ns(t),
            f"/targets/{label}",
            "foxglove.PoseInFrame",
            {
                "timestamp": stamp(t),
                "frame_id": WORLD,
                "pose": {"position": position, "orientation": identity},
            },
        )
        if kind == "robot":
            yield Message(
                _ns(t),
                "/tf",
                "foxglove.FrameTransform",
                {
                    "timestamp": stamp(t),
                    "parent_frame_id": WORLD,
                    "child_frame_id": label,
                    "translation": position,
                    "rotation": identity,
                },
            )


def _image_messages(images: Iterable[LatestImage], names: dict[int, str]) -> list[Message]:
    return [
        Message(
            _ns(im.t),
            f"/cameras/{names[im.camera_id]}/image",
            "foxglove.CompressedImage",
            {
                "timestamp": stamp(im.t),
                "frame_id": camera_frame(names[im.camera_id]),
                "data": base64.b64encode(im.jpeg).decode("ascii"),
                "format": "jpeg",
            },
        )
        for im in sorted(images, key=lambda im: im.t)
        if im.camera_id in names
    ]


def export_messages(
    session: Session,
    space_id: int,
    since: float,
    until: float,
    images: Iterable[LatestImage] = (),
) -> Iterator[Message]:
    """Yield the messages of space `space_id` between `since` and `until` (Unix s, both
    included) in log-time order: calibrations and camera poses at `since`, detections, track
    points (and robot poses), and the given camera images that lie in the range."""
    cameras = list(session.scalars(select(Camera).where(Camera.space_id == space_id)))
    names = {c.id: c.name for c in cameras}
    in_range = [im for im in images if since <= im.t <= until]
    yield from heapq.merge(
        _camera_messages(cameras, since),
        _detection_messages(session, space_id, since, until, names),
        _track_messages(session, space_id, since, until),
        _image_messages(in_range, names),
        key=lambda m: m.log_time,
    )


# -- the file ------------------------------------------------------------------------------------


class _Chunks:
    """A write-only stream that keeps what is written until `drain` takes it."""

    def __init__(self) -> None:
        self._parts: list[bytes] = []
        self._size = 0
        self._position = 0

    def write(self, data: bytes) -> int:
        self._parts.append(bytes(data))
        self._size += len(data)
        self._position += len(data)
        return len(data)

    def tell(self) -> int:
        return self._position

    def flush(self) -> None:
        pass

    @property
    def pending(self) -> int:
        return self._size

    def drain(self) -> bytes:
        data = b"".join(self._parts)
        self._parts, self._size = [], 0
        return data


def mcap_stream(
    messages: Iterable[Message], *, metadata: dict[str, str] | None = None
) -> Iterator[bytes]:
    """Yield an MCAP file of `messages` (JSON, Foxglove schemas) in pieces as it is written."""
    sink = _Chunks()
    writer = Writer(sink, compression=CompressionType.ZSTD)  # type: ignore[arg-type]
    writer.start(profile="", library="intspace")
    schemas: dict[str, int] = {}
    channels: dict[str, int] = {}
    sequence: dict[int, int] = {}
    for m in messages:
        channel = channels.get(m.topic)
        if channel is None:
            schema = schemas.get(m.schema)
            if schema is None:
                schema = writer.register_schema(
                    name=m.schema,
                    encoding="jsonschema",
                    data=json.dumps(SCHEMAS[m.schema]).encode(),
                )
                schemas[m.schema] = schema
            channel = writer.register_channel(
                topic=m.topic, message_encoding="json", schema_id=schema
            )
            channels[m.topic] = channel
        seq = sequence.get(channel, 0)
        sequence[channel] = seq + 1
        writer.add_message(
            channel_id=channel,
            log_time=m.log_time,
            publish_time=m.log_time,
            sequence=seq,
            data=json.dumps(m.payload, allow_nan=False).encode(),
        )
        if sink.pending >= _FLUSH_BYTES:
            yield sink.drain()
    if metadata:
        writer.add_metadata("intspace", metadata)
    writer.finish()
    yield sink.drain()


def check_range(since: float, until: float, max_range_s: float) -> str | None:
    """Return why [since, until] cannot be exported (with the limit), or None when it can."""
    if not (math.isfinite(since) and math.isfinite(until)):
        return "since and until must be finite Unix times (seconds)"
    if until <= since:
        return f"until ({until:.3f}) must be after since ({since:.3f})"
    if until - since > max_range_s:
        return (
            f"the range spans {until - since:.0f} s; an export spans at most {max_range_s:.0f} s "
            "(INTSPACE_EXPORT_MAX_RANGE_S): export it in parts"
        )
    return None
