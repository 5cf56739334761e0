"""The latest image of each real camera, as its camera node uploaded it, kept in memory.

A camera of the twin has its frames in the twin; a real camera's image reaches the service
only from its node (PUT /cameras/{id}/frame), at most once a second, so that the dashboard can
show it (placing the camera from floor points needs it). One JPEG per camera is kept, the
newest: memory is bounded by the number of cameras times the frame size limit.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

# A camera sends at most one frame per this many seconds.
MIN_FRAME_INTERVAL_S = 1.0


@dataclass(frozen=True)
class StoredFrame:
    """A camera's latest uploaded JPEG and when it arrived (Unix s, the service's clock)."""

    jpeg: bytes
    received: float


class LatestFrames:
    """The newest uploaded frame of each camera, with a per-camera rate limit."""

    def __init__(
        self,
        min_interval_s: float = MIN_FRAME_INTERVAL_S,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
    ) -> None:
        self._min_interval = min_interval_s
        self._clock = clock
        self._wall = wall
        self._lock = threading.Lock()
        self._frames: dict[int, StoredFrame] = {}
        self._last: dict[int, float] = {}

    def wait_s(self, camera_id: int) -> float:
        """Return how long camera `camera_id` must wait before its next frame (0: it may
        send now)."""
        with self._lock:
            last = self._last.get(camera_id)
        if last is None:
            return 0.0
        return max(0.0, self._min_interval - (self._clock() - last))

    def put(self, camera_id: int, jpeg: bytes) -> float:
        """Keep `jpeg` as the camera's latest frame unless it came too soon; return 0 when
        kept, else the seconds to wait."""
        with self._lock:
            now = self._clock()
            last = self._last.get(camera_id)
            if last is not None and now - last < self._min_interval:
                return self._min_interval - (now - last)
            self._last[camera_id] = now
            self._frames[camera_id] = StoredFrame(jpeg, self._wall())
            return 0.0

    def get(self, camera_id: int) -> StoredFrame | None:
        """Return the camera's latest uploaded frame, None when it has sent none."""
        with self._lock:
            return self._frames.get(camera_id)

    def forget(self, camera_id: int) -> None:
        """Drop a (deleted) camera's frame."""
        with self._lock:
            self._frames.pop(camera_id, None)
            self._last.pop(camera_id, None)
