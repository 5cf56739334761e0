"""Parser of multipart/x-mixed-replace bodies (MJPEG over HTTP), fed bytes as they arrive.

Each part is a header block (`Name: value` lines, ended by an empty line) and a body; the body
is `Content-Length` bytes when the header gives it (as the service and most IP cameras do), else
what lies before the next boundary line. RFC 2046 §5.1.1: a boundary line is `--boundary`,
preceded by CRLF except at the start of the body.
"""

from __future__ import annotations

from dataclasses import dataclass

from core.errors import InvalidInput

# A part larger than this (bytes) is not a camera frame: the stream is broken or hostile.
MAX_PART_BYTES = 32 * 2**20


@dataclass(frozen=True)
class MjpegPart:
    """One part: its headers (names lower-cased) and its body (a JPEG)."""

    headers: dict[str, str]
    body: bytes

    @property
    def timestamp(self) -> float | None:
        """Return the part's X-Timestamp (capture time, Unix seconds), None when absent or
        not a finite number."""
        value = self.headers.get("x-timestamp")
        if value is None:
            return None
        try:
            t = float(value)
        except ValueError:
            return None
        return t if t == t and abs(t) != float("inf") else None


def boundary_of(content_type: str) -> bytes:
    """Return the boundary named by a multipart Content-Type header value.

    Raises InvalidInput when the type is not multipart or names no boundary."""
    kind, _, params = content_type.partition(";")
    if not kind.strip().lower().startswith("multipart/"):
        raise InvalidInput(f"not a multipart stream (Content-Type {content_type!r})")
    for param in params.split(";"):
        key, _, value = param.strip().partition("=")
        if key.strip().lower() == "boundary" and value.strip():
            boundary = value.strip().strip('"')
            # Some cameras put the dashes in the parameter too.
            return boundary[2:].encode() if boundary.startswith("--") else boundary.encode()
    raise InvalidInput(f"the multipart Content-Type {content_type!r} names no boundary")


class MjpegParser:
    """Incremental parser: `feed(bytes)` returns the parts completed by those bytes.

    A part cut short by the end of the stream is never returned (the reader reconnects and
    starts a new parser). Raises InvalidInput when a part exceeds `max_part_bytes` or a header
    block is not text.
    """

    def __init__(self, boundary: bytes, *, max_part_bytes: int = MAX_PART_BYTES) -> None:
        if not boundary:
            raise InvalidInput("the multipart boundary must not be empty")
        self._delim = b"--" + boundary
        self._max = int(max_part_bytes)
        self._buf = bytearray()
        self._headers: dict[str, str] | None = None  # of the part being read, once parsed

    def feed(self, data: bytes) -> list[MjpegPart]:
        """Add stream bytes; return the parts they complete, in order."""
        self._buf += data
        out: list[MjpegPart] = []
        while True:
            part = self._next()
            if part is None:
                break
            out.append(part)
        if len(self._buf) > self._max + 4096:
            raise InvalidInput(
                f"an MJPEG part exceeds {self._max} bytes without ending; not a camera stream"
            )
        return out

    def _next(self) -> MjpegPart | None:
        buf = self._buf
        if self._headers is None:
            start = buf.find(self._delim)
            if start < 0:
                # Keep a tail that may hold the start of a boundary split across chunks.
                del buf[: max(0, len(buf) - len(self._delim))]
                return None
            end = buf.find(b"\r\n\r\n", start)
            if end < 0:
                return None
            lines = bytes(buf[start + len(self._delim) : end]).split(b"\r\n")
            headers: dict[str, str] = {}
            for line in lines[1:]:  # lines[0]: what follows the boundary on its line
                name, sep, value = line.partition(b":")
                if not sep:
                    continue
                try:
                    headers[name.decode("ascii").strip().lower()] = value.decode("latin-1").strip()
                except UnicodeDecodeError as exc:
                    raise InvalidInput("an MJPEG part's header is not ASCII text") from exc
            del buf[: end + 4]
            self._headers = headers
        headers = self._headers
        length = headers.get("content-length")
        if length is not None and length.isdigit():
            n = int(length)
            if n > self._max:
                raise InvalidInput(f"an MJPEG part announces {n} bytes, more than {self._max}")
            if len(buf) < n:
                return None
            body = bytes(buf[:n])
            del buf[:n]
        else:
            cut = buf.find(b"\r\n" + self._delim)
            if cut < 0:
                return None
            body = bytes(buf[:cut])
            del buf[:cut]
        self._headers = None
        return MjpegPart(headers, body)
