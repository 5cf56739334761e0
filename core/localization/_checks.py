"""Argument checks shared by the localisation functions (done once, at the boundary)."""

from __future__ import annotations

import math
from collections.abc import Sequence

from core.errors import InvalidInput
from core.localization.cameras import NetworkCamera


def as_cameras(cameras: Sequence[NetworkCamera] | NetworkCamera) -> tuple[NetworkCamera, ...]:
    """Return the cameras as a non-empty tuple of NetworkCamera; raise InvalidInput otherwise."""
    cams = (cameras,) if isinstance(cameras, NetworkCamera) else tuple(cameras)
    if not cams:
        raise InvalidInput("no cameras given")
    for c in cams:
        if not isinstance(c, NetworkCamera):
            raise InvalidInput(f"cameras must be NetworkCamera instances, got {type(c).__name__}")
    return cams


def check_height(height: float) -> float:
    """Return the plane height as a float; raise InvalidInput unless finite."""
    try:
        h = float(height)
    except (TypeError, ValueError):
        raise InvalidInput(f"height must be a number of metres, got {height!r}") from None
    if not math.isfinite(h):
        raise InvalidInput(f"height must be a finite number of metres, got {height}")
    return h


def check_time(t: object) -> float:
    """Return a time in seconds as a float; raise InvalidInput unless a finite number."""
    try:
        value = float(t)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InvalidInput(f"t must be a time in seconds, got {t!r}") from None
    if not math.isfinite(value):
        raise InvalidInput(f"t must be a finite time in seconds, got {t}")
    return value
