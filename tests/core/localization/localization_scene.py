"""The localisation tests' scene: a ceiling-camera network over an 8 m x 6 m room.

Four cameras in the corners at 2.8 m, their axes about 26 degrees below the horizon towards the
far side of the room, 1280 x 800 images, a moderately wide lens (77 degrees horizontal) with the
barrel distortion and small decentring typical of such lenses. Within the field of view (ideal
radius < 1.05) the radial factor's derivative 1 + 3 k1 r^2 + 5 k2 r^4 + 7 k3 r^6 stays > 0.6,
so undistortion is unique there.
"""

from __future__ import annotations

import numpy as np

from core.localization import NetworkCamera

ROOM = (8.0, 6.0)
CAMERA_HEIGHT = 2.8
IMAGE_SIZE = (1280, 800)
DIST = np.array([-0.12, 0.03, 5e-4, -3e-4, -2e-3])


def make_cameras(n: int = 4) -> list[NetworkCamera]:
    """Return n (<= 4) corner cameras of the room, each with slightly different intrinsics."""
    w, d = ROOM
    corners = [(0.15, 0.15), (w - 0.15, 0.15), (w - 0.15, d - 0.15), (0.15, d - 0.15)]
    cams = []
    for i, (x, y) in enumerate(corners[:n]):
        f = 800.0 + 15.0 * i
        K = np.array([[f, 0.0, 640.0 + 3 * i], [0.0, f * 1.001, 400.0 - 2 * i], [0.0, 0.0, 1.0]])
        # Aim past the room centre so each camera covers the far side of the room.
        target = (w / 2 + 0.2 * (w / 2 - x), d / 2 + 0.2 * (d / 2 - y), 0.0)
        cams.append(
            NetworkCamera.looking_at(
                K, DIST * (1 + 0.05 * i), (x, y, CAMERA_HEIGHT), target, IMAGE_SIZE, f"cam{i}"
            )
        )
    return cams


def floor_points(rng: np.random.Generator, n: int, height: float, margin: float = 0.1):
    """Return n points (n, 3) uniform over the room's floor (inset by margin) at Z = height."""
    w, d = ROOM
    xy = rng.uniform([margin, margin], [w - margin, d - margin], size=(n, 2))
    return np.column_stack([xy, np.full(n, height)])


def observe(cameras, points, sigma: float, rng: np.random.Generator | None):
    """Return (pixels (C, B, 2), visible (C, B)) of points, with Gaussian noise sigma (px)."""
    px = np.stack([c.project(points) for c in cameras])
    vis = np.stack([c.in_view(points) for c in cameras])
    if rng is not None and sigma > 0:
        px = px + rng.normal(0.0, sigma, px.shape)
    return px, vis
