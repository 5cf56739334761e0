"""Camera sources read by one thread each, which keeps only the newest frame (frames.NewestFrame).

* HTTP MJPEG read with httpx (`MjpegHttpSource`): the way to read the service's own streams,
  which need an Authorization header and carry each frame's capture time (X-Timestamp), two
  things OpenCV's FFmpeg reader cannot give per source. The JPEG is decoded by the detector.
* Everything else with OpenCV (`OpenCvSource`): a USB index (the platform's backend), a video
  file, an RTSP or HTTP URL (the FFmpeg backend with open and read timeouts of 2 s). A file is
  replayed at its own frame rate, or as fast as it decodes, and ends.

A read that times out (no frame for 2 s) is a stall; the source is reopened with back-off
(0.25 s doubling to 1 s: a camera that returns waits at most 1 s for the next attempt, then
the open, which FFmpeg spends about 2 s probing an RTSP stream in; spec 08 asks for 5 s).
Counters: frames, stalls, reconnects; frames per second over the last 2 s.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Literal

import cv2
import httpx

from core.errors import InvalidInput
from server.node.frames import Frame, NewestFrame
from server.node.mjpeg import MjpegParser, boundary_of

log = logging.getLogger("intspace.node")

TIMEOUT_S = 2.0
_BACKOFF_FIRST_S = 0.25
_BACKOFF_MAX_S = 1.0
_FPS_WINDOW_S = 2.0


@dataclass
class SourceStats:
    """What a source counts; read by the heartbeat thread (plain ints: no torn reads)."""

    frames: int = 0
    stalls: int = 0
    reconnects: int = 0
    last_received: float | None = None
    last_t: float | None = None
    error: str | None = None
    _recent: deque[float] = field(default_factory=lambda: deque(maxlen=1000))

    def frame(self, received: float, t: float | None) -> None:
        """Count a frame received at local time `received`, stamped `t` (or None)."""
        self.frames += 1
        self.last_received, self.last_t = received, t
        self._recent.append(received)

    def fps(self, now: float) -> float:
        """Return frames per second over the last 2 s (local clock `now`)."""
        recent = [r for r in list(self._recent) if r > now - _FPS_WINDOW_S]
        if len(recent) < 2:
            return 0.0
        span = max(now - recent[0], recent[-1] - recent[0])
        return (len(recent) - 1) / span if span > 0 else 0.0


class Source:
    """A camera read by a thread into `frames` until `stop`."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.frames = NewestFrame()
        self.stats = SourceStats()
        self.finished = threading.Event()
        self._stop = threading.Event()
        self._seq = 0
        self._thread = threading.Thread(target=self._run, name=f"source-{name}", daemon=True)

    def start(self) -> None:
        """Start reading."""
        self._thread.start()

    def stop(self) -> None:
        """Stop reading (at the next frame or timeout)."""
        self._stop.set()
        self.frames.close()

    def join(self, timeout: float | None = None) -> None:
        """Wait for the reader thread."""
        self._thread.join(timeout)

    def _publish(
        self,
        t: float | None,
        *,
        image=None,
        jpeg: bytes | None = None,
        captured: float | None = None,
    ) -> None:
        self._seq += 1
        received = time.time()
        self.stats.frame(received, t)
        self.frames.put(Frame(self._seq, received, t, image=image, jpeg=jpeg, captured=captured))

    def _problem(self, message: str) -> None:
        # Said once per distinct problem, not once per retry.
        if message != self.stats.error:
            log.warning("camera %s: %s", self.name, message)
        self.stats.error = message

    def _run(self) -> None:
        backoff = _BACKOFF_FIRST_S
        opened_once = False
        try:
            while not self._stop.is_set():
                if opened_once:
                    self.stats.reconnects += 1
                opened_once = True
                before = self.stats.frames
                if self._read() == "ended":
                    return
                if self.stats.frames > before:
                    backoff = _BACKOFF_FIRST_S
                self._stop.wait(backoff)
                backoff = min(2 * backoff, _BACKOFF_MAX_S)
        finally:
            self.finished.set()
            self.frames.close()

    def _read(self) -> Literal["ended", "retry"]:
        raise NotImplementedError


class MjpegHttpSource(Source):
    """An HTTP(S) MJPEG stream read with httpx, with extra request headers (a bearer token)."""

    def __init__(self, name: str, url: str, headers: dict[str, str] | None = None) -> None:
        super().__init__(name)
        self.url = url
        self._headers = dict(headers or {})
        self._client = httpx.Client(timeout=httpx.Timeout(TIMEOUT_S), headers=self._headers)

    def _read(self) -> Literal["ended", "retry"]:
        try:
            with self._client.stream("GET", self.url) as response:
                if response.status_code != 200:
                    response.read()
                    detail = response.text[:200].replace("\n", " ")
                    self._problem(f"{self.url} answered {response.status_code}: {detail}")
                    return "retry"
                parser = MjpegParser(boundary_of(response.headers.get("content-type", "")))
                if self.stats.error is not None:
                    log.warning("camera %s: reading %s again", self.name, self.url)
                self.stats.error = None
                for chunk in response.iter_bytes():
                    for part in parser.feed(chunk):
                        self._publish(part.timestamp, jpeg=part.body)
                    if self._stop.is_set():
                        return "ended"
            self._problem(f"{self.url}: the stream ended")
            self.stats.stalls += 1
        except httpx.TimeoutException:
            self._problem(f"{self.url}: no data for {TIMEOUT_S:g} s (stalled)")
            self.stats.stalls += 1
        except httpx.TransportError as exc:
            self._problem(f"{self.url}: {type(exc).__name__}: {exc}")
        except InvalidInput as exc:
            self._problem(f"{self.url}: {exc}")
        return "retry"


class OpenCvSource(Source):
    """A USB index, video file or RTSP/HTTP URL read with OpenCV. A file plays at its own
    frame rate (`realtime`) or as fast as it decodes, once. With `source_fps` a file's frame k
    was captured at t0 + k / source_fps (t0: when it was opened, the node's clock) and plays at
    that rate: a container's frame rate can be wrong (PETS 2009's says 10 for 7)."""

    def __init__(
        self,
        name: str,
        source: int | str,
        *,
        realtime: bool = True,
        source_fps: float | None = None,
    ) -> None:
        super().__init__(name)
        self.source = source
        self.is_file = isinstance(source, str) and "://" not in source
        self.realtime = realtime
        if source_fps is not None and not source_fps > 0:
            raise InvalidInput(f"source_fps must be > 0, got {source_fps}")
        self.source_fps = source_fps if self.is_file else None

    def _open(self) -> cv2.VideoCapture:
        params = [
            cv2.CAP_PROP_OPEN_TIMEOUT_MSEC,
            int(TIMEOUT_S * 1000),
            cv2.CAP_PROP_READ_TIMEOUT_MSEC,
            int(TIMEOUT_S * 1000),
        ]
        if isinstance(self.source, int):  # a USB camera: the platform's own backend
            return cv2.VideoCapture(self.source, cv2.CAP_ANY, params)
        return cv2.VideoCapture(self.source, cv2.CAP_FFMPEG, params)

    def _read(self) -> Literal["ended", "retry"]:
        cap = self._open()
        try:
            if not cap.isOpened():
                self._problem(f"cannot open {self.source!r}")
                return "ended" if self.is_file else "retry"
            self.stats.error = None
            period = 0.0
            if self.is_file and self.realtime:
                fps = self.source_fps or cap.get(cv2.CAP_PROP_FPS)
                period = 1.0 / fps if fps and fps > 0 else 0.0
            next_time = time.monotonic()
            start = time.time()
            index = 0
            while not self._stop.is_set():
                ok, image = cap.read()
                if not ok or image is None:
                    if self.is_file:
                        log.info("camera %s: %s ended", self.name, self.source)
                        return "ended"
                    self._problem(f"{self.source!r}: no frame for {TIMEOUT_S:g} s (stalled)")
                    self.stats.stalls += 1
                    return "retry"
                captured = None
                if self.source_fps is not None:
                    captured = start + index / self.source_fps
                index += 1
                self._publish(None, image=image, captured=captured)
                if period:
                    next_time = max(next_time + period, time.monotonic() - period)
                    self._stop.wait(max(0.0, next_time - time.monotonic()))
            return "ended"
        finally:
            cap.release()
