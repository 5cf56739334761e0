"""Camera poses built from where a camera is and what it looks at."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike


def look_at(position: ArrayLike, target: ArrayLike, up: ArrayLike = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Return the camera-to-world transform (4, 4) of an OpenCV camera (z forward, x right, y
    down) at `position` looking at `target`: its x axis along z x `up`, so that `up` (world +Z
    by default) is up in the image."""
    p = np.asarray(position, dtype=float)
    z = np.asarray(target, dtype=float) - p
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = p
    return T
