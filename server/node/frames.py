"""The newest frame of a source, handed from its reader thread to its detector thread.

A reader that queued every frame would let a detector slower than the camera fall further
behind with each frame (seconds within tens of seconds); the holder keeps only the newest and
counts the frames a newer one replaced before the detector took them (dropped).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class Frame:
    """One frame: the decoded BGR image or its JPEG bytes (decoded by whoever uses it), its
    capture time from the stream (Unix seconds, the service's clock; None when the stream has
    no per-frame stamp), when the node received it (its own clock), its sequence number, and
    its capture time on the node's clock where the source knows it without a stamp (a video
    file of known frame rate: its start plus the frame's place in it)."""

    seq: int
    received: float
    t: float | None = None
    image: NDArray[np.uint8] | None = None
    jpeg: bytes | None = None
    captured: float | None = None


class NewestFrame:
    """A one-slot mailbox: `put` replaces, `take` waits for a frame newer than the last taken."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._frame: Frame | None = None
        self._taken = 0  # sequence number of the last frame taken
        self._closed = False
        self.dropped = 0

    def put(self, frame: Frame) -> None:
        """Offer a frame (its seq must grow); an untaken older one is dropped."""
        with self._cond:
            if self._frame is not None and self._frame.seq > self._taken:
                self.dropped += 1
            self._frame = frame
            self._cond.notify_all()

    def take(self, timeout: float | None = None) -> Frame | None:
        """Return the newest frame not taken yet, waiting up to `timeout` s (None: forever);
        None on timeout, or once closed and the last frame taken."""
        with self._cond:

            def fresh() -> bool:
                return self._frame is not None and self._frame.seq > self._taken

            self._cond.wait_for(lambda: self._closed or fresh(), timeout)
            if not fresh():
                return None
            assert self._frame is not None
            self._taken = self._frame.seq
            return self._frame

    def close(self) -> None:
        """Wake every waiting `take` and wait no more: the newest frame can still be taken,
        then `take` returns None at once."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    @property
    def closed(self) -> bool:
        """Whether `close` was called."""
        return self._closed


class HandOver(NewestFrame):
    """A newest-frame holder whose producer can wait until its frame was taken, so that a fast
    replay (a video file or a recording with --fast) hands every frame to the detector."""

    def take(self, timeout: float | None = None) -> Frame | None:
        """Return the newest frame not taken yet (NewestFrame.take) and wake the producer."""
        frame = super().take(timeout)
        with self._cond:
            self._cond.notify_all()
        return frame

    def wait_taken(self, seq: int, stop: threading.Event) -> None:
        """Wait until frame `seq` was taken (or the holder closed, or `stop`)."""
        with self._cond:
            while self._taken < seq and not self._closed and not stop.is_set():
                self._cond.wait(0.1)
