"""The landmark payload: a compact, versioned text schema carried by the QR symbol.

Layout (fields separated by "|", text fields percent-encoded as in RFC 3986 so that "|", ","
and "%" never appear raw inside a field; numbers in plain decimal):

    ISL1|O|<id>|<class>|<name>|<room>|<sx,sy,sz>|<x,y,z,qx,qy,qz,qw>|<hint,hint,...>|<crc>
    ISL1|S|<id>|<name>|<room>|<x,y,z,qx,qy,qz,qw>|<id,id,...>|<crc>

"ISL" is the magic, "1" the version, O/S the kind (object mark / signpost). The object mark
carries the object's class, name, room, size (metres, along the mark's x, y, z) and the grasp
frame T_mark_grasp (position metres, quaternion x, y, z, w) with handling hints; the signpost
its pose T_world_mark, its room and the ids of the neighbouring signposts (the navigation graph's
edges). <crc> is the CRC-32 (ISO-HDLC, as zlib.crc32) of the UTF-8 bytes before the last "|",
as 8 upper-case hexadecimal digits. Lengths are quantised to 0.1 mm and quaternion components to
1e-5 when a record is built, so that a record survives `decode_payload(encode_payload(r))`
exactly.
"""

from __future__ import annotations

import math
import re
import zlib
from dataclasses import dataclass
from urllib.parse import quote, unquote

from core.errors import InvalidInput

MAGIC = "ISL"
VERSION = 1
_HEAD = f"{MAGIC}{VERSION}"
_SEP = "|"
_LIST = ","
_LENGTH_DECIMALS = 4
_QUAT_DECIMALS = 5
_MAX_TEXT = 64
_MAX_LENGTH = 1000.0  # metres: a home, a care home, a lab
_FIELDS = {"O": 10, "S": 8}
_HEX8 = re.compile(r"[0-9A-F]{8}")
_INT = re.compile(r"(0|[1-9][0-9]{0,8})")
_NUM = re.compile(r"-?(0|[1-9][0-9]*)(\.[0-9]+)?")


class PayloadError(InvalidInput):
    """A QR text that is not a valid landmark payload: foreign (not ours), of an unknown version,
    truncated, corrupt (checksum mismatch) or malformed. `reason` is one of "foreign",
    "version", "truncated", "checksum", "malformed"; the message says what was wrong."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


def _quantise(values: tuple[float, ...], decimals: int, what: str) -> tuple[float, ...]:
    out = []
    for v in values:
        f = float(v)
        if not math.isfinite(f):
            raise InvalidInput(f"{what} must be finite numbers, got {values!r}")
        if abs(f) > _MAX_LENGTH:
            raise InvalidInput(f"{what} must be within +-{_MAX_LENGTH:g}, got {values!r}")
        q = round(f, decimals)
        out.append(0.0 if q == 0 else q)  # no "-0.0"
    return tuple(out)


def _pose7(pose: tuple[float, ...], what: str) -> tuple[float, ...]:
    """Return (x, y, z, qx, qy, qz, qw) quantised, the quaternion normalised with qw >= 0."""
    if len(pose) != 7:
        raise InvalidInput(f"{what} must be (x, y, z, qx, qy, qz, qw), got {len(pose)} values")
    p = _quantise(tuple(pose[:3]), _LENGTH_DECIMALS, what)
    q = [float(v) for v in pose[3:]]
    n = math.sqrt(sum(v * v for v in q))
    if not math.isfinite(n) or n < 1e-6:
        raise InvalidInput(f"{what}: the quaternion (x, y, z, w) must be non-zero, got {q}")
    if q[3] < 0:
        q = [-v for v in q]
    if abs(n - 1.0) > 1e-4:  # a quantised unit quaternion is kept as is: decoding is idempotent
        q = [v / n for v in q]
    return p + _quantise(tuple(q), _QUAT_DECIMALS, what)


def _text(value: str, what: str) -> str:
    s = str(value)
    if not s or len(s) > _MAX_TEXT or not s.isprintable():
        raise InvalidInput(f"{what} must be 1-{_MAX_TEXT} printable characters, got {s!r}")
    return s


def _ident(value: int, what: str = "id") -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 999_999_999:
        raise InvalidInput(f"{what} must be an integer in 0..999999999, got {value!r}")
    return value


IDENTITY_POSE = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)


@dataclass(frozen=True)
class ObjectMark:
    """The record of an object mark: what the object is and how to handle it.

    id: landmark id; object_class ("cup"), name ("blue cup"), room; size (sx, sy, sz) metres,
    the object's extent along the mark's axes; grasp (x, y, z, qx, qy, qz, qw): the grasp frame
    in the mark frame (metres, unit quaternion); hints: handling hints ("fragile", "upright").
    """

    id: int
    object_class: str
    name: str
    room: str
    size: tuple[float, float, float] = (0.0, 0.0, 0.0)
    grasp: tuple[float, ...] = IDENTITY_POSE
    hints: tuple[str, ...] = ()

    kind = "object"

    def __post_init__(self) -> None:
        _ident(self.id)
        for name in ("object_class", "name", "room"):
            object.__setattr__(self, name, _text(getattr(self, name), name))
        if len(self.size) != 3:
            raise InvalidInput(f"size must be (sx, sy, sz) metres, got {self.size!r}")
        size = _quantise(tuple(self.size), _LENGTH_DECIMALS, "size")
        if min(size) < 0:
            raise InvalidInput(f"size must be >= 0 metres, got {self.size!r}")
        object.__setattr__(self, "size", size)
        object.__setattr__(self, "grasp", _pose7(tuple(self.grasp), "grasp"))
        object.__setattr__(self, "hints", tuple(_text(h, "hint") for h in self.hints))


@dataclass(frozen=True)
class Signpost:
    """The record of a signpost: a place in the navigation map.

    id: landmark id; name: the place ("kitchen door"); room; pose (x, y, z, qx, qy, qz, qw):
    T_world_mark (metres, unit quaternion); neighbours: ids of the signposts reachable from here.
    """

    id: int
    name: str
    room: str
    pose: tuple[float, ...] = IDENTITY_POSE
    neighbours: tuple[int, ...] = ()

    kind = "signpost"

    def __post_init__(self) -> None:
        _ident(self.id)
        object.__setattr__(self, "name", _text(self.name, "name"))
        object.__setattr__(self, "room", _text(self.room, "room"))
        object.__setattr__(self, "pose", _pose7(tuple(self.pose), "pose"))
        nb = tuple(_ident(n, "neighbour id") for n in self.neighbours)
        if self.id in nb:
            raise InvalidInput(f"signpost {self.id} lists itself as a neighbour")
        object.__setattr__(self, "neighbours", nb)


Record = ObjectMark | Signpost


def _num(x: float, decimals: int) -> str:
    # The value is already rounded to `decimals`: this prints it exactly, without a "-0".
    s = f"{x:.{decimals}f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def _esc(s: str) -> str:
    return quote(s, safe=" ")


def _nums(values: tuple[float, ...], decimals: tuple[int, ...]) -> str:
    return _LIST.join(_num(v, d) for v, d in zip(values, decimals, strict=True))


_L3 = (_LENGTH_DECIMALS,) * 3
_P7 = _L3 + (_QUAT_DECIMALS,) * 4


def encode_payload(record: Record) -> str:
    """Return the QR text of a record (ObjectMark or Signpost), checksum appended."""
    if isinstance(record, ObjectMark):
        fields = [
            _HEAD,
            "O",
            str(record.id),
            _esc(record.object_class),
            _esc(record.name),
            _esc(record.room),
            _nums(record.size, _L3),
            "" if record.grasp == IDENTITY_POSE else _nums(record.grasp, _P7),
            _LIST.join(_esc(h) for h in record.hints),
        ]
    elif isinstance(record, Signpost):
        fields = [
            _HEAD,
            "S",
            str(record.id),
            _esc(record.name),
            _esc(record.room),
            _nums(record.pose, _P7),
            _LIST.join(str(n) for n in record.neighbours),
        ]
    else:
        raise InvalidInput(f"record must be an ObjectMark or a Signpost, got {type(record)}")
    body = _SEP.join(fields)
    return f"{body}{_SEP}{zlib.crc32(body.encode()):08X}"


def _parse_nums(text: str, count: int, what: str) -> tuple[float, ...]:
    parts = text.split(_LIST)
    if len(parts) != count or not all(_NUM.fullmatch(p) for p in parts):
        raise PayloadError("malformed", f"payload field {what} must hold {count} numbers: {text!r}")
    return tuple(float(p) for p in parts)


def _parse_text(text: str, what: str) -> str:
    if not text:
        raise PayloadError("malformed", f"payload field {what} is empty")
    try:
        return unquote(text, errors="strict")
    except UnicodeDecodeError:
        raise PayloadError("malformed", f"payload field {what} is not UTF-8: {text!r}") from None


def decode_payload(text: str | bytes) -> Record:
    """Return the record (ObjectMark or Signpost) a QR text carries.

    Checks, in order: the magic (else reason "foreign"), the version ("version"), the field
    count ("truncated"), the checksum ("checksum"), then every field ("malformed"). Raises
    PayloadError naming the problem; never returns a partial record.
    """
    if isinstance(text, bytes | bytearray):
        try:
            text = bytes(text).decode("utf-8")
        except UnicodeDecodeError:
            raise PayloadError(
                "foreign", "not a landmark payload: the bytes are not UTF-8"
            ) from None
    if not isinstance(text, str):
        raise PayloadError("foreign", f"not a landmark payload: {type(text).__name__}")
    if not text.startswith(MAGIC):
        raise PayloadError("foreign", f"not a landmark payload (no {MAGIC!r} magic): {text[:24]!r}")
    fields = text.split(_SEP)
    if fields[0] != _HEAD:
        raise PayloadError(
            "version",
            f"landmark payload version {fields[0][len(MAGIC) :]!r} is not supported "
            f"(this reader knows {VERSION}); update the software",
        )
    kind = fields[1] if len(fields) > 1 else ""
    if kind not in _FIELDS:
        if len(fields) < 3:
            raise PayloadError("truncated", f"landmark payload is truncated: {text!r}")
        raise PayloadError("malformed", f"unknown landmark kind {kind!r} (O or S expected)")
    if len(fields) != _FIELDS[kind]:
        reason = "truncated" if len(fields) < _FIELDS[kind] else "malformed"
        raise PayloadError(
            reason, f"landmark payload has {len(fields)} fields, {_FIELDS[kind]} expected"
        )
    body, crc = text.rsplit(_SEP, 1)
    if not _HEX8.fullmatch(crc) or int(crc, 16) != zlib.crc32(body.encode()):
        raise PayloadError("checksum", "landmark payload checksum mismatch: the text is corrupt")
    if not _INT.fullmatch(fields[2]):
        raise PayloadError(
            "malformed", f"landmark id must be a non-negative integer: {fields[2]!r}"
        )
    ident = int(fields[2])
    try:
        if kind == "O":
            hints = () if not fields[8] else fields[8].split(_LIST)
            return ObjectMark(
                id=ident,
                object_class=_parse_text(fields[3], "class"),
                name=_parse_text(fields[4], "name"),
                room=_parse_text(fields[5], "room"),
                size=_parse_nums(fields[6], 3, "size"),  # type: ignore[arg-type]
                grasp=_parse_nums(fields[7], 7, "grasp") if fields[7] else IDENTITY_POSE,
                hints=tuple(_parse_text(h, "hint") for h in hints),
            )
        nbs = () if not fields[6] else fields[6].split(_LIST)
        if not all(_INT.fullmatch(n) for n in nbs):
            raise PayloadError("malformed", f"neighbour ids must be integers: {fields[6]!r}")
        return Signpost(
            id=ident,
            name=_parse_text(fields[3], "name"),
            room=_parse_text(fields[4], "room"),
            pose=_parse_nums(fields[5], 7, "pose"),
            neighbours=tuple(int(n) for n in nbs),
        )
    except PayloadError:
        raise
    except InvalidInput as exc:
        raise PayloadError("malformed", f"landmark payload field out of range: {exc}") from None
