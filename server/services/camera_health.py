"""The health of every camera, from the frames its source delivers: a camera node's heartbeats
(POST /cameras/{id}/heartbeat) and the digital twin's loop report the same way to one book per
service, which GET /cameras and GET /cameras/{id} read."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any

from server.schemas.registry import CameraHealth, CameraHeartbeat

# A camera whose node has not reported for this long (s) is offline.
OFFLINE_AFTER_S = 5.0
# A camera with no frame for this long (s), or two frame periods if longer, is stalled.
STALLED_AFTER_S = 2.0


@dataclass(frozen=True)
class _Beat:
    received: float
    body: CameraHeartbeat
    first_received: float
    online_since: float | None


class CameraHealthBook:
    """The latest heartbeat of each camera, in memory (a restarted service learns them again
    within a second); statuses are computed when read, so no timer runs."""

    def __init__(self, clock: Any = time.time) -> None:
        self._clock = clock
        self._lock = threading.Lock()
        self._beats: dict[int, _Beat] = {}

    @staticmethod
    def _status(beat: _Beat | None, now: float) -> tuple[str, float | None]:
        if beat is None:
            return "offline", None
        if now - beat.received > OFFLINE_AFTER_S:
            return "offline", beat.received + OFFLINE_AFTER_S
        fps = beat.body.fps
        quiet = max(STALLED_AFTER_S, 2.0 / fps) if fps > 0 else STALLED_AFTER_S
        last = beat.body.last_frame_t
        if last is None:
            return "stalled", beat.first_received
        if now - last > quiet:
            return "stalled", last + quiet
        return "online", beat.online_since

    def beat(self, camera_id: int, body: CameraHeartbeat) -> CameraHealth:
        """Record a heartbeat; return the camera's health with it."""
        now = self._clock()
        with self._lock:
            old = self._beats.get(camera_id)
            was, _ = self._status(old, now)
            first = now if old is None or was == "offline" else old.first_received
            beat = _Beat(now, body, first, old.online_since if old is not None else None)
            if self._status(beat, now)[0] == "online" and was != "online":
                beat = _Beat(now, body, first, now)
            self._beats[camera_id] = beat
        return self._health(beat, now)

    def health(self, camera_id: int) -> CameraHealth:
        """Return the camera's health now (offline, since null, when it never reported)."""
        now = self._clock()
        with self._lock:
            beat = self._beats.get(camera_id)
        return self._health(beat, now)

    def forget(self, camera_id: int) -> None:
        """Drop a deleted camera's heartbeats."""
        with self._lock:
            self._beats.pop(camera_id, None)

    def _health(self, beat: _Beat | None, now: float) -> CameraHealth:
        status_, since = self._status(beat, now)
        if beat is None:
            return CameraHealth(status="offline")
        b = beat.body
        return CameraHealth(
            status=status_,  # type: ignore[arg-type]
            since=since,
            fps=b.fps,
            stalls=b.stalls,
            reconnects=b.reconnects,
            dropped=b.dropped,
            dropped_detections=b.dropped_detections,
            clock_offset_s=b.clock_offset_s,
            last_frame_t=b.last_frame_t,
            last_heartbeat=beat.received,
        )
