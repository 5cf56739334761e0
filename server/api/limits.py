"""Request limits: body size per endpoint (the global cap stays the ceiling), enforced before the
body is read (Content-Length) and while it is streamed (chunked uploads); image dimensions read
from the file's header, so that an image is refused for its size before it is decoded."""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass

from fastapi import HTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from server.api.errors import FieldProblem, problem_response
from server.middleware import HttpMiddleware, StartWatch

MiB = 2**20

# Bodies each endpoint takes, at most (bytes); the first pattern matching the method and path
# wins, and the global cap (INTSPACE_MAX_REQUEST_BYTES) bounds them all. Sized from what a
# request legitimately holds, so that validating the largest one costs the process well under
# 150 MB: an observation with every field is ~200 bytes of JSON, so 20,000 of them (the batch
# cap) fit in 4 MiB; a correspondence calibration of 60 views of 500 points is ~3 MiB; a
# registry record (a 10,000-vertex polygon, a 100,000-character kinematic model) is under 1 MiB.
BODY_LIMITS: tuple[tuple[str, re.Pattern[str], int], ...] = (
    ("POST", re.compile(r"^/api/v1/calibration-runs/upload$"), 1 << 62),
    ("POST", re.compile(r"^/api/v1/observations$"), 4 * MiB),
    ("POST", re.compile(r"^/api/v1/calibration-runs$"), 8 * MiB),
    # One photo (its own 16 MiB file cap and the pixel cap still apply).
    ("POST", re.compile(r"^/api/v1/landmarks/detect$"), 32 * MiB),
    # A camera node's latest frame (server.api.placement.MAX_FRAME_BYTES).
    ("PUT", re.compile(r"^/api/v1/cameras/\d+/frame$"), 4 * MiB),
    ("*", re.compile(r"^/api/v1/"), 1 * MiB),
)


def body_limit(method: str, path: str, ceiling: int) -> int:
    """Return the body cap (bytes) of `method` on `path`: its endpoint's, at most `ceiling`."""
    for want, pattern, limit in BODY_LIMITS:
        if (want == "*" or want == method) and pattern.match(path):
            return min(limit, ceiling)
    return ceiling


class _TooLarge(HTTPException):
    # An HTTPException so that FastAPI's body parsing passes it on instead of answering 400.
    def __init__(self, max_bytes: int) -> None:
        super().__init__(413, _too_large(max_bytes))


def _too_large(max_bytes: int) -> str:
    return f"the request body exceeds this endpoint's limit of {max_bytes} bytes"


class RequestSizeLimit(HttpMiddleware):
    """ASGI middleware answering 413 (problem JSON) to bodies over the endpoint's limit
    (`body_limit`, at most `max_bytes`). The refused body is read and dropped, up to
    `drain_bytes` (default `max_bytes`), so that the client's keep-alive connection stays
    usable; past that the server closes it."""

    def __init__(self, app: ASGIApp, max_bytes: int, drain_bytes: int | None = None) -> None:
        super().__init__(app)
        self.max_bytes = max_bytes
        self.drain_bytes = max_bytes if drain_bytes is None else drain_bytes

    async def http(self, scope: Scope, receive: Receive, send: Send) -> None:
        limit = body_limit(scope["method"], scope["path"], self.max_bytes)
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None:
            try:
                too_large = int(declared) > limit
            except ValueError:
                too_large = False
            if too_large:
                await self._reject(limit, 0, scope, receive, send)
                return

        received = 0
        ended = False

        async def limited_receive() -> Message:
            nonlocal received, ended
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                ended = not message.get("more_body", False)
                if received > limit:
                    raise _TooLarge(limit)
            return message

        watch = StartWatch(send)
        try:
            await self.app(scope, limited_receive, watch)
        except _TooLarge:
            if watch.started:
                raise
            await self._reject(limit, received, scope, receive, send, ended=ended)

    async def _reject(
        self,
        limit: int,
        received: int,
        scope: Scope,
        receive: Receive,
        send: Send,
        *,
        ended: bool = False,
    ) -> None:
        # Drop the rest of the body (memory: one chunk at a time); past drain_bytes the
        # connection is not worth keeping and the server closes it.
        while not ended and received <= self.drain_bytes:
            message = await receive()
            if message["type"] != "http.request":
                break
            received += len(message.get("body", b""))
            ended = not message.get("more_body", False)
        response = problem_response(413, _too_large(limit))
        await response(scope, receive, send)


# Image headers


@dataclass(frozen=True)
class ImageHeader:
    """What an image file's header says: its format and size in pixels."""

    format: str
    width: int
    height: int

    @property
    def pixels(self) -> int:
        """Return width x height."""
        return self.width * self.height


READABLE_FORMATS = ("PNG", "JPEG", "BMP", "TIFF", "WebP", "GIF", "PNM")


def read_image_header(data: bytes) -> ImageHeader | None:
    """Return the format and size an image's header declares, without decoding it; None when
    `data` does not start like one of READABLE_FORMATS or its header is cut short."""
    try:
        for reader in (_png, _jpeg, _bmp, _tiff, _webp, _gif, _pnm):
            header = reader(data)
            if header is not None:
                return header
    except (struct.error, IndexError, ValueError):
        return None
    return None


def check_image_size(data: bytes, max_pixels: int, field: str, name: str) -> ImageHeader:
    """Return the header of the uploaded image `data`; raise FieldProblem 413 naming the pixel
    cap when it declares more than `max_pixels` pixels, 415 when its size cannot be read from
    its header (not a format of READABLE_FORMATS). Nothing is decoded."""
    header = read_image_header(data)
    if header is None:
        raise FieldProblem(
            415,
            field,
            f"{name!r} is not an image whose size can be read before decoding: send "
            + ", ".join(READABLE_FORMATS),
            "form",
        )
    if header.width <= 0 or header.height <= 0 or header.pixels > max_pixels:
        raise FieldProblem(
            413,
            field,
            f"{name!r} is a {header.format} of {header.width}x{header.height} = {header.pixels} "
            f"pixels, over the limit of {max_pixels} pixels per image (INTSPACE_MAX_IMAGE_PIXELS)",
            "form",
        )
    return header


def _png(data: bytes) -> ImageHeader | None:
    if not data.startswith(b"\x89PNG\r\n\x1a\n") or data[12:16] != b"IHDR":
        return None
    width, height = struct.unpack(">II", data[16:24])
    return ImageHeader("PNG", width, height)


# Start-of-frame markers: every SOFn but DHT (C4), JPG (C8) and DAC (CC).
_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


def _jpeg(data: bytes) -> ImageHeader | None:
    if not data.startswith(b"\xff\xd8"):
        return None
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0x01, *range(0xD0, 0xD8)):  # markers without a length
            i += 2
            continue
        (length,) = struct.unpack(">H", data[i + 2 : i + 4])
        if marker in _SOF:
            height, width = struct.unpack(">HH", data[i + 5 : i + 9])
            return ImageHeader("JPEG", width, height)
        if marker == 0xDA or length < 2:  # scan data before any frame header
            return None
        i += 2 + length
    return None


def _bmp(data: bytes) -> ImageHeader | None:
    if not data.startswith(b"BM"):
        return None
    (dib,) = struct.unpack("<I", data[14:18])
    if dib == 12:  # OS/2 BITMAPCOREHEADER
        width, height = struct.unpack("<HH", data[18:22])
    else:
        width, height = struct.unpack("<ii", data[18:26])
    return ImageHeader("BMP", width, abs(height))


def _tiff(data: bytes) -> ImageHeader | None:
    if data[:4] == b"II*\x00":
        e = "<"
    elif data[:4] == b"MM\x00*":
        e = ">"
    else:
        return None
    (offset,) = struct.unpack(e + "I", data[4:8])
    (count,) = struct.unpack(e + "H", data[offset : offset + 2])
    size: dict[int, int] = {}
    for k in range(count):
        entry = data[offset + 2 + 12 * k : offset + 14 + 12 * k]
        tag, kind = struct.unpack(e + "HH", entry[:4])
        if tag in (256, 257):
            # SHORT (3) or LONG (4), value in the entry itself.
            fmt = e + ("H" if kind == 3 else "I")
            size[tag] = struct.unpack(fmt, entry[8 : 8 + struct.calcsize(fmt)])[0]
    if 256 not in size or 257 not in size:
        return None
    return ImageHeader("TIFF", size[256], size[257])


def _webp(data: bytes) -> ImageHeader | None:
    if data[:4] != b"RIFF" or data[8:12] != b"WEBP":
        return None
    chunk = data[12:16]
    if chunk == b"VP8 ":
        width, height = struct.unpack("<HH", data[26:30])
        return ImageHeader("WebP", width & 0x3FFF, height & 0x3FFF)
    if chunk == b"VP8L":
        (bits,) = struct.unpack("<I", data[21:25])
        return ImageHeader("WebP", (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1)
    if chunk == b"VP8X":
        w = int.from_bytes(data[24:27], "little") + 1
        h = int.from_bytes(data[27:30], "little") + 1
        return ImageHeader("WebP", w, h)
    return None


def _gif(data: bytes) -> ImageHeader | None:
    if data[:6] not in (b"GIF87a", b"GIF89a"):
        return None
    width, height = struct.unpack("<HH", data[6:10])
    return ImageHeader("GIF", width, height)


_PNM_TOKEN = re.compile(rb"(?:\s|#[^\n]*\n)*(\d+)")


def _pnm(data: bytes) -> ImageHeader | None:
    if len(data) < 3 or data[0:1] != b"P" or data[1:2] not in b"123456":
        return None
    first = _PNM_TOKEN.match(data, 2, 2 + 1024)
    second = _PNM_TOKEN.match(data, first.end(), first.end() + 1024) if first else None
    if first is None or second is None:
        return None
    return ImageHeader("PNM", int(first[1]), int(second[1]))
