"""The projector and the planned path in the live scene: parsing and the drawn views."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from server.scene._entries import ProjectorEntry
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


def parse_projector(projector: ProjectorEntry) -> ProjectorView:
    """Return the view of a projector (T_world_projector 4x4 rigid, spot [x, y] or None);
    raise InvalidInput naming what is wrong."""
    pose = pose_from_transform(projector.T_world_projector, "T_world_projector")
    spot = projector.spot
    xy: tuple[float, float] | None = None
    if spot is not None:
        try:
            values = [float(v) for v in spot]
        except (TypeError, ValueError):
            raise InvalidInput(f"a projector's spot must be [x, y] metres, got {spot!r}") from None
        if len(values) != 2 or not all(math.isfinite(v) for v in values):
            raise InvalidInput(f"a projector's spot must be a finite [x, y], got {spot!r}")
        xy = (values[0], values[1])
    return ProjectorView(projector.name or "projector", pose, xy)
