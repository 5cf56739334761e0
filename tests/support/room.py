"""A 4 m x 3 m room watched by ceiling cameras 2.8 m up, looking at its middle, for the tests and
benches that post synthetic observations of people to a running service: the cameras' lens,
a person's marker height, a detection's pixel noise and how long after capture a node posts."""

from __future__ import annotations

from collections.abc import Sequence

from core.localization import NetworkCamera

K = [[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]]
DIST = [-0.1, 0.01, 0.0005, -0.0003, 0.0]
HEIGHT = 1.0
SIGMA_PX = 0.5
# A camera node posts a frame once it has read and detected it: its capture time is some tens
# of milliseconds before the post (detection takes ~30 ms at 30 fps, then HTTP on the LAN).
CAPTURE_DELAY_S = 0.05
MIDDLE = (2.0, 1.5, 0.0)


def ceiling_cameras(
    positions: Sequence[Sequence[float]], dist: Sequence[float] | None = DIST
) -> list[NetworkCamera]:
    """Return 640 x 480 cameras with K (and `dist`) at `positions` (world metres), each looking
    at the room's middle."""
    return [NetworkCamera.looking_at(K, dist, p, MIDDLE, (640, 480)) for p in positions]
