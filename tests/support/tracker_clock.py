"""The tracking service's clock held by the test, and waiting until its thread has taken the
frames posted: what a tracker takes then depends on what was posted, never on the time."""

from __future__ import annotations

from typing import Any

from tests.support.waiting import wait_until


class HeldClock:
    """The service's clock, moved by the test (set `t`)."""

    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def wait_processed(tracking: Any, frames: int, stalled_after_s: float = 5.0) -> None:
    """Wait until the tracker thread of `tracking` (the TrackingService) has processed
    `frames` frames in all; raise Stalled when it takes none for `stalled_after_s` seconds."""
    wait_until(
        lambda: tracking.frames_processed >= frames,
        what=f"the tracker taking {frames} frames in all",
        stalled_after_s=stalled_after_s,
        progress=lambda: tracking.frames_processed,
        poll_s=0.005,
    )
