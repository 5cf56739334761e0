"""Live MJPEG streams of the twin's cameras, served as an IP camera serves its stream.

`GET /cameras/{id}/stream.mjpg` answers multipart/x-mixed-replace: one JPEG part per frame the
twin renders, each with an `X-Timestamp` header (the frame's capture time, Unix seconds on the
service's clock), so a camera node reads the twin exactly as it reads a real camera (spec 08).
The stream is read with a bearer token in the Authorization header, never in the URL (URLs end
up in logs). Nothing runs for a camera nobody watches: a frame is encoded only inside a
connected client's generator, once per frame however many clients share it.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import AsyncIterator
from typing import Annotated

import cv2
from fastapi import APIRouter, HTTPException, Path, Request, status
from fastapi.responses import StreamingResponse
from starlette.concurrency import run_in_threadpool

from server.api.deps import ReadAccess, TwinDep
from server.api.errors import PROBLEM_RESPONSES
from server.schemas.common import MAX_ID
from server.services.twin import Twin, TwinFrame

router = APIRouter(tags=["cameras"], responses=PROBLEM_RESPONSES)

BOUNDARY = "intspaceframe"
# How often a connected client's generator looks for a new frame (s): a fraction of the
# twin's fastest frame period (30 Hz), so a frame waits at most this long before it is sent.
_POLL_S = 0.01
# A client's generator ends after this long without a new frame (the twin paused or stopped);
# the client reconnects, as it does to a camera that stalled.
_IDLE_S = 30.0
# Quality 90 with full-resolution chroma (4:4:4): the robot's marker and the landmarks are
# found by colour, and 4:2:0 halves the chroma's resolution (at quality 85 it moved the marker's
# detected centre by 0.12 px RMS, 0.06 px at 4:4:4), which a camera for measurement should not.
_JPEG_PARAMS = [
    cv2.IMWRITE_JPEG_QUALITY,
    90,
    cv2.IMWRITE_JPEG_SAMPLING_FACTOR,
    cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444,
]


class _EncodedFrames:
    """The JPEG of each camera's latest frame, encoded once for every client."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._jpeg: dict[int, tuple[float, bytes]] = {}

    def jpeg(self, frame: TwinFrame) -> bytes:
        """Return the JPEG bytes of `frame` (encoded on first request)."""
        with self._lock:
            cached = self._jpeg.get(frame.camera_id)
        if cached is not None and cached[0] == frame.t:
            return cached[1]
        ok, buf = cv2.imencode(".jpg", frame.image, _JPEG_PARAMS)
        if not ok:  # pragma: no cover - an 8-bit BGR image always encodes
            raise RuntimeError(f"JPEG encoding of camera {frame.camera_id}'s frame failed")
        data = buf.tobytes()
        with self._lock:
            self._jpeg[frame.camera_id] = (frame.t, data)
        return data


_ENCODED = _EncodedFrames()


def part(jpeg: bytes, t: float) -> bytes:
    """Return one multipart part: boundary, headers (type, length, X-Timestamp) and the JPEG."""
    head = (
        f"--{BOUNDARY}\r\nContent-Type: image/jpeg\r\nContent-Length: {len(jpeg)}\r\n"
        f"X-Timestamp: {t:.6f}\r\n\r\n"
    ).encode("ascii")
    return head + jpeg + b"\r\n"


def _twin_camera(twin: Twin | None, camera_id: int) -> Twin:
    if twin is None:
        raise HTTPException(
            status.HTTP_404_NOT_FOUND,
            detail=f"no stream of camera {camera_id}: the digital twin is not running "
            "(INTSPACE_SIMULATION=true); a real camera streams from its own address",
        )
    if camera_id not in twin.camera_ids.values():
        raise HTTPException(
            status.HTTP_404_NOT_FOUND,
            detail=f"no stream of camera {camera_id}: it is not a camera of the twin; a real "
            "camera streams from its own address",
        )
    return twin


async def _frames(request: Request, twin: Twin, camera_id: int) -> AsyncIterator[bytes]:
    """Yield a part per new frame of the camera until the client leaves or the twin idles."""
    loop = asyncio.get_running_loop()
    last_t: float | None = None
    last_new = loop.time()
    while True:
        if await request.is_disconnected():
            return
        frame = twin.frame(camera_id)
        if frame is not None and frame.t != last_t:
            last_t, last_new = frame.t, loop.time()
            jpeg = await run_in_threadpool(_ENCODED.jpeg, frame)
            yield part(jpeg, frame.t)
        elif loop.time() - last_new > _IDLE_S:
            return
        else:
            await asyncio.sleep(_POLL_S)


@router.get(
    "/cameras/{camera_id}/stream.mjpg",
    dependencies=[ReadAccess],
    response_class=StreamingResponse,
    responses={
        200: {
            "content": {f"multipart/x-mixed-replace; boundary={BOUNDARY}": {}},
            "description": "One JPEG part per frame, each with an X-Timestamp header (the "
            "capture time, Unix seconds).",
        }
    },
)
async def camera_stream(
    camera_id: Annotated[int, Path(ge=1, le=MAX_ID)], request: Request, twin: TwinDep
) -> StreamingResponse:
    """Stream a twin camera's frames as they are rendered (MJPEG, multipart/x-mixed-replace),
    each part stamped with its capture time in an `X-Timestamp` header. The stream ends when
    the client leaves, or after 30 s without a new frame (the twin paused)."""
    return StreamingResponse(
        _frames(request, _twin_camera(twin, camera_id), camera_id),
        media_type=f"multipart/x-mixed-replace; boundary={BOUNDARY}",
        headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"},
    )
