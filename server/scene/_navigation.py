"""The projector and the planned path in the live scene: parsing and the drawn views."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from server.scene._geometry import Pose, pose_from_transform

# Beyond this many points a planned path is a mistake (the planner's paths have tens).
MAX_PATH_POINTS = 10_000


@dataclass(frozen=True)
class ProjectorView:
    """The ceiling projector as drawn: its name, its mount pose (T_world_projector) and the
    floor point its beam is drawn to (x, y m), if any."""

    name: str
    pose: Pose
    spot: tuple[float, float] | None


def parse_path(points: Sequence[Sequence[float]] | NDArray[np.float64]) -> NDArray[np.float64]:
    """Return a planned path as an (N, 2) float array of world (x, y) metres (N may be 0, which
    clears it); raise InvalidInput for anything else, or a single point."""
    try:
        p = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"a planned path must be a list of [x, y] points: {exc}") from None
    if p.size == 0:
        return np.zeros((0, 2))
    if p.ndim != 2 or p.shape[1] != 2:
        raise InvalidInput(f"a planned path must be a list of [x, y] points, got shape {p.shape}")
    if len(p) < 2 or len(p) > MAX_PATH_POINTS:
        raise InvalidInput(
            f"a planned path has 2 to {MAX_PATH_POINTS} points, got {len(p)}; an empty list "
            "clears it"
        )
    if not np.all(np.isfinite(p)):
        raise InvalidInput("a planned path's points must be finite")
    return p.copy()


def parse_projector(projector: Mapping[str, Any]) -> ProjectorView:
    """Return the view of {"name", "T_world_projector" (4x4 rigid), "spot": [x, y] or None};
    raise InvalidInput naming what is wrong."""
    if not isinstance(projector, Mapping):
        raise InvalidInput(f"a projector must be a mapping, got {type(projector).__name__}")
    name = str(projector.get("name") or "projector")
    pose = pose_from_transform(projector.get("T_world_projector"), "T_world_projector")
    spot = projector.get("spot")
    if spot is not None:
        try:
            xy = [float(v) for v in spot]
        except (TypeError, ValueError):
            raise InvalidInput(f"a projector's spot must be [x, y] metres, got {spot!r}") from None
        if len(xy) != 2 or not all(math.isfinite(v) for v in xy):
            raise InvalidInput(f"a projector's spot must be a finite [x, y], got {spot!r}")
        spot = (xy[0], xy[1])
    return ProjectorView(name, pose, spot)
