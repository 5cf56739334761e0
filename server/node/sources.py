"""Camera sources read by one thread each, which keeps only the newest frame (frames.NewestFrame).

* HTTP MJPEG read with httpx (`MjpegHttpSource`): the way to read the service's own streams,
  which need an Authorization header and carry each frame's capture time (X-Timestamp), two
  things OpenCV's FFmpeg reader cannot give per source. The JPEG is decoded by the detector.
* Everything else with OpenCV (`OpenCvSource`): a USB index (the platform's backend), a video
  file, an RTSP or HTTP URL (the FFmpeg backend with open and read timeouts of 2 s). A file is
  replayed at its own frame rate, or (fast) as fast as the detector takes its frames, every one
  of them, stamped with the clip's own timing; it ends with the file.

`check` opens a source before its thread starts: a source that cannot be opened then is an
error (`SourceUnavailable`, saying which source, why and what to do), not a retry. Once a
stream has been opened, losing it is not: a read that times out (no frame for 2 s) is a stall,
and the source is reopened with back-off, 0.5 s doubling to 2 s for the first minute of an
outage (spec 08: a camera that returns is read again within 5 s, and FFmpeg spends about 2 s
probing an RTSP stream it opens), then doubling to 30 s (a camera gone for good costs a
connection attempt every half minute). Each change of state is said once: connected, stalled
or lost, reconnecting, still down after a minute, back. The FFmpeg and OpenCV libraries' own
messages (two lines per failed attempt) are silenced (`quiet_video_libraries`).

Counters: frames, stalls, reconnects; frames per second over the last 2 s. URLs are shown with
their password masked (`describe_source`).
"""

from __future__ import annotations

import logging
import math
import os
import socket
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal
from urllib.parse import urlsplit, urlunsplit

import cv2
import httpx

from core.errors import InvalidInput
from server.node.frames import Frame, HandOver, NewestFrame
from server.node.mjpeg import MjpegParser, boundary_of

log = logging.getLogger("intspace.node")

TIMEOUT_S = 2.0
BACKOFF_FIRST_S = 0.5
# The longest wait between attempts during the first minute of an outage, and after it.
BACKOFF_EARLY_MAX_S = 2.0
BACKOFF_EARLY_S = 60.0
BACKOFF_MAX_S = 30.0
_FPS_WINDOW_S = 2.0
# A fast replay's clip starts this far ahead of the clock (s): its first frames, detected and
# posted within it, are never behind the service's window however busy the machine is for a
# moment; the frames ahead of the clock wait in the service's reorder buffer until their time.
FAST_LEAD_S = 0.5
# FFmpeg's AV_LOG_QUIET.
_FFMPEG_QUIET = "-8"


class SourceUnavailable(Exception):
    """A source that cannot be opened at start: its message names the source, says why and
    what to do, and is the one line the node prints before it exits."""


def quiet_video_libraries() -> None:
    """Keep FFmpeg's and OpenCV's own messages (\"[tcp @ 0x...] Connection refused\", \"[ WARN:0]
    ... can't open\") out of the node's output: the node says what happened once, in its own
    words. A user who wants them sets OPENCV_FFMPEG_LOGLEVEL (FFmpeg's level, read when OpenCV
    first opens an FFmpeg capture) or OPENCV_LOG_LEVEL (read when cv2 is imported)."""
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", _FFMPEG_QUIET)
    if "OPENCV_LOG_LEVEL" not in os.environ:
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)


def describe_source(source: int | str) -> str:
    """Return a source as it may be shown: a USB index, a path, or a URL with its password
    masked (an IP camera's URL often carries the camera's credentials)."""
    if isinstance(source, int):
        return f"USB camera {source}"
    if "://" not in source:
        return source
    parts = urlsplit(source)
    if parts.password is None:
        return source
    host = parts.hostname or ""
    if parts.port is not None:
        host = f"{host}:{parts.port}"
    return urlunsplit(parts._replace(netloc=f"{parts.username}:***@{host}"))


def _endpoint(url: str) -> tuple[str, int] | None:
    parts = urlsplit(url)
    default = {"rtsp": 554, "rtsps": 322, "http": 80, "https": 443}.get(parts.scheme.lower())
    try:
        port = parts.port or default
    except ValueError:
        return None
    if not parts.hostname or port is None:
        return None
    return parts.hostname, port


def unreachable(url: str) -> str | None:
    """Return why a TCP connection to the URL's host and port fails (it does not resolve, it
    is refused, it times out), None when it succeeds or the URL names no host."""
    endpoint = _endpoint(url)
    if endpoint is None:
        return None
    host, port = endpoint
    try:
        with socket.create_connection((host, port), timeout=TIMEOUT_S):
            return None
    except socket.gaierror:
        return f"the host name {host!r} does not resolve (check the address, or use the IP)"
    except ConnectionRefusedError:
        return (
            f"{host}:{port} refused the connection (the camera is off, or serves on another port)"
        )
    except TimeoutError:
        return f"{host}:{port} did not answer within {TIMEOUT_S:g} s (wrong address, firewall)"
    except OSError as exc:
        return f"{host}:{port}: {exc.strerror or exc}"


def _why_not_opened(source: int | str) -> str:
    """Return why OpenCV could not open a source, and what to do (it says only that it did not)."""
    if isinstance(source, int):
        device = Path(f"/dev/video{source}")
        if sys.platform.startswith("linux") and not device.exists():
            return (
                f"there is no {device}: plug the camera in, or give another index (ls /dev/video*)"
            )
        if sys.platform.startswith("linux") and not os.access(device, os.R_OK):
            return f"no permission to read {device}: add this user to the 'video' group"
        return "the camera did not open: is another program using it?"
    if "://" not in source:
        path = Path(source)
        if not path.exists():
            return "no such file: give a video file, a recording folder, a USB index or a URL"
        if path.is_dir():
            return "a folder, but not a recording (no recording.json in it)"
        if not os.access(path, os.R_OK):
            return "permission denied: make the file readable by this user"
        return "FFmpeg cannot decode it: not a video, or in a codec this OpenCV lacks"
    why = unreachable(source)
    if why is not None:
        return why
    return (
        "the server answered but gave no video: check the URL's path and the user and password "
        "in it (the camera's manual gives its stream's URL)"
    )


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
        self.frames: NewestFrame = NewestFrame()
        self.stats = SourceStats()
        self.finished = threading.Event()
        self._stop = threading.Event()
        self._seq = 0
        self._thread = threading.Thread(target=self._run, name=f"source-{name}", daemon=True)
        # The outage under way: since when (monotonic), the attempts made, the reasons said
        # (each once), whether the slower back-off was announced.
        self._down_since: float | None = None
        self._attempts = 0
        self._said: set[str] = set()
        self._slow = False

    @property
    def label(self) -> str:
        """Return the source as it may be shown (a URL's password masked)."""
        return self.name

    def check(self) -> None:
        """Open the source once, before `start`. Raises SourceUnavailable saying why it cannot
        be read. The base class has nothing to check."""

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
        if self.stats.frames == 0:
            log.info("camera %s: connected to %s", self.name, self.label)
        elif self._down_since is not None:
            log.info(
                "camera %s: back after %.1f s (%d reconnect attempt(s))",
                self.name,
                time.monotonic() - self._down_since,
                self._attempts,
            )
        self._down_since, self._attempts, self._slow = None, 0, False
        self._said.clear()
        self.stats.error = None
        self._seq += 1
        received = time.time()
        self.stats.frame(received, t)
        self.frames.put(Frame(self._seq, received, t, image=image, jpeg=jpeg, captured=captured))

    def _problem(self, message: str) -> None:
        # Said once per distinct problem, not once per retry.
        if message != self.stats.error:
            log.warning("camera %s: %s", self.name, message)
        self.stats.error = message

    def _lost(self, reason: str) -> None:
        """The stream stopped giving frames, or an attempt to reopen it failed, for `reason`."""
        self.stats.error = reason
        if self._down_since is None:
            self._down_since = time.monotonic()
            log.warning("camera %s: %s", self.name, reason)
            log.info(
                "camera %s: reconnecting (every %g s doubling to %g s, then to %g s after a "
                "minute)",
                self.name,
                BACKOFF_FIRST_S,
                BACKOFF_EARLY_MAX_S,
                BACKOFF_MAX_S,
            )
        elif reason not in self._said:
            log.warning("camera %s: still unreachable: %s", self.name, reason)
        self._said.add(reason)

    def _backoff(self) -> float:
        """Return how long to wait before the next attempt of the outage under way."""
        down = 0.0 if self._down_since is None else time.monotonic() - self._down_since
        cap = BACKOFF_EARLY_MAX_S if down < BACKOFF_EARLY_S else BACKOFF_MAX_S
        if cap == BACKOFF_MAX_S and not self._slow:
            log.warning(
                "camera %s: still down after %.0f s; trying again at most every %g s",
                self.name,
                down,
                BACKOFF_MAX_S,
            )
            self._slow = True
        return min(BACKOFF_FIRST_S * 2.0 ** min(self._attempts, 16), cap)

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                if self._read() == "ended":
                    return
                self._stop.wait(self._backoff())
                self._attempts += 1
                self.stats.reconnects += 1
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

    @property
    def label(self) -> str:
        """Return the URL, its password masked."""
        return describe_source(self.url)

    def check(self) -> None:
        """Raise SourceUnavailable unless the URL answers 200 with a multipart stream."""
        where = f"cannot open {self.label}"
        try:
            with self._client.stream("GET", self.url) as response:
                if response.status_code != 200:
                    hint = {
                        401: "the stream wants credentials (for the service's own streams: a "
                        "token that may read this camera in INTSPACE_TOKEN)",
                        403: "the credentials may not read this stream",
                        404: "no stream at that path: check the URL",
                    }.get(response.status_code, "check the URL")
                    raise SourceUnavailable(
                        f"{where}: it answered {response.status_code} "
                        f"{response.reason_phrase}; {hint}"
                    )
                boundary_of(response.headers.get("content-type", ""))
        except httpx.TransportError as exc:
            why = unreachable(self.url) or f"{type(exc).__name__}: {exc}"
            raise SourceUnavailable(f"{where}: {why}") from None
        except InvalidInput as exc:
            raise SourceUnavailable(
                f"{where}: {exc}, not an MJPEG stream (give the camera's MJPEG URL, or its RTSP "
                "URL)"
            ) from None

    def _read(self) -> Literal["ended", "retry"]:
        try:
            with self._client.stream("GET", self.url) as response:
                if response.status_code != 200:
                    response.read()
                    detail = response.text[:200].replace("\n", " ")
                    self._lost(f"{self.label} answered {response.status_code}: {detail}")
                    return "retry"
                parser = MjpegParser(boundary_of(response.headers.get("content-type", "")))
                for chunk in response.iter_bytes():
                    for part in parser.feed(chunk):
                        self._publish(part.timestamp, jpeg=part.body)
                    if self._stop.is_set():
                        return "ended"
            self._lost("stalled: the stream ended")
            self.stats.stalls += 1
        except httpx.TimeoutException:
            self._lost(f"stalled: no data for {TIMEOUT_S:g} s")
            self.stats.stalls += 1
        except httpx.TransportError as exc:
            self._lost(f"connection lost: {type(exc).__name__}: {exc}")
        except InvalidInput as exc:
            self._lost(f"{self.label}: {exc}")
        return "retry"


class OpenCvSource(Source):
    """A USB index, video file or RTSP/HTTP URL read with OpenCV. A file plays once: at its own
    frame rate (`realtime`), or as fast as the detector takes its frames, every one, frame k
    stamped t0 + k / (the file's frame rate), t0 the `clock` (the service's) at the first plus
    FAST_LEAD_S. With `source_fps` that is the file's frame rate whatever its container says
    (PETS 2009's says 10 for 7): at its own pace, frame k was captured at t0 + k / source_fps
    (t0: when it was opened, the node's clock) and plays at that rate."""

    def __init__(
        self,
        name: str,
        source: int | str,
        *,
        realtime: bool = True,
        clock: Callable[[], float] = time.time,
        source_fps: float | None = None,
    ) -> None:
        super().__init__(name)
        self.source = source
        self.is_file = isinstance(source, str) and "://" not in source
        self.realtime = realtime
        if source_fps is not None and not source_fps > 0:
            raise InvalidInput(f"source_fps must be > 0, got {source_fps}")
        self.source_fps = source_fps if self.is_file else None
        self._clock = clock
        self._cap: cv2.VideoCapture | None = None  # opened by check, read by the thread
        self.fps = 0.0  # the frame rate a file says it has (0: unknown, or not a file)
        self._handover: HandOver | None = None
        if self.is_file and not realtime:
            self._handover = HandOver()
            self.frames = self._handover

    @property
    def label(self) -> str:
        """Return the source, a URL's password masked."""
        return describe_source(self.source)

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

    def check(self) -> None:
        """Open the capture (kept for the reader). Raises SourceUnavailable saying why it does
        not open, or why a file cannot be replayed fast (it does not say its frame rate)."""
        cap = self._open()
        if not cap.isOpened():
            cap.release()
            raise SourceUnavailable(f"cannot open {self.label}: {_why_not_opened(self.source)}")
        if self._handover is not None and not (self.source_fps or _frame_rate(cap)):
            cap.release()
            raise SourceUnavailable(
                f"{self.label} does not say its frame rate, which --fast needs to give its "
                "frames the clip's own timing: replay it at its own pace (without --fast)"
            )
        self._cap = cap

    def _read(self) -> Literal["ended", "retry"]:
        cap, self._cap = self._cap or self._open(), None
        try:
            if not cap.isOpened():
                if self.is_file:
                    self._problem(f"cannot open {self.label}: {_why_not_opened(self.source)}")
                    return "ended"
                self._lost(f"cannot open {self.label}: {_why_not_opened(self.source)}")
                return "retry"
            fps = self.fps = self.source_fps or _frame_rate(cap)
            period = 1.0 / fps if self.is_file and self.realtime and fps else 0.0
            next_time = time.monotonic()
            start = time.time()
            t0: float | None = None
            k = 0
            while not self._stop.is_set():
                ok, image = cap.read()
                if not ok or image is None:
                    if self.is_file:
                        log.info("camera %s: %s ended after %d frame(s)", self.name, self.label, k)
                        return "ended"
                    self._lost(f"stalled: no frame for {TIMEOUT_S:g} s")
                    self.stats.stalls += 1
                    return "retry"
                if self._handover is not None:
                    # Every frame, at the clip's own pace in its stamps, not in the wall's.
                    t0 = self._clock() + FAST_LEAD_S if t0 is None else t0
                    self._publish(t0 + k / fps, image=image)
                    self._handover.wait_taken(self._seq, self._stop)
                else:
                    captured = None
                    if self.source_fps is not None:
                        captured = start + k / self.source_fps
                    self._publish(None, image=image, captured=captured)
                k += 1
                if period:
                    next_time = max(next_time + period, time.monotonic() - period)
                    self._stop.wait(max(0.0, next_time - time.monotonic()))
            return "ended"
        finally:
            cap.release()

    def stop(self) -> None:
        """Stop reading; release a capture opened by `check` and never read."""
        super().stop()
        if self._cap is not None and not self._thread.is_alive():
            self._cap.release()
            self._cap = None


def _frame_rate(cap: cv2.VideoCapture) -> float:
    """Return the frame rate a capture reports, 0 when it reports none (or nonsense)."""
    fps = float(cap.get(cv2.CAP_PROP_FPS))
    return fps if math.isfinite(fps) and 0 < fps <= 1000 else 0.0
