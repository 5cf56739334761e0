"""The projector and the planned path in the live scene: the path as a green poly-line just
above the tracks, the projector as a frame at its mount with its beam to the spot it draws.

`NavigationLayer` is the part of SceneService that holds and draws them; it uses the service's
lock (`_cond`) and viser server (`_server`).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from server.scene._entries import ProjectorEntry
from server.scene._geometry import Pose, as_xy_points, pose_from_transform

# Beyond this many points a planned path is a mistake (the planner's paths have tens).
MAX_PATH_POINTS = 10_000
# The planned path in green a little above the tracks; the projector's beam in laser red.
_COLOR_PATH = (22, 163, 74)
_COLOR_BEAM = (220, 38, 38)
_PATH_HEIGHT = 0.016


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
    p = as_xy_points(points, "a planned path")
    if len(p) == 0:
        return p
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


class NavigationLayer:
    """The planned path and the projector of SceneService: thread-safe state changes, drawing
    on the scene's worker."""

    _cond: threading.Condition
    _server: Any

    def _init_navigation(self) -> None:
        self._path = np.zeros((0, 2))  # the planned path, (N, 2) m
        self._projector: ProjectorView | None = None
        self._dirty_navigation = False
        # What the worker has drawn; read by planned_path() / projector() under _cond.
        self._drawn_path = np.zeros((0, 2))
        self._drawn_projector: ProjectorView | None = None

    def _restart_navigation(self) -> None:
        """Under _cond, when the server (re)starts: the path and projector are drawn again."""
        self._dirty_navigation = True

    def _navigation_dirty(self) -> bool:
        return self._dirty_navigation

    def _take_navigation(self) -> tuple[NDArray[np.float64], ProjectorView | None] | None:
        """Under _cond: the path and projector if they changed since the last call, else None."""
        navigation = (self._path, self._projector) if self._dirty_navigation else None
        self._dirty_navigation = False
        return navigation

    # -- state changes (any thread) ----------------------------------------------------------

    def set_planned_path(self, points: Sequence[Sequence[float]]) -> None:
        """Replace the planned path by the poly-line through `points` ([[x, y], ...], world m,
        at least 2), drawn just above the floor; an empty list removes it. Raises InvalidInput
        (nothing changes) for malformed points."""
        path = parse_path(points)
        with self._cond:
            self._path = path
            self._dirty_navigation = True
            self._cond.notify_all()

    def set_projector(self, projector: ProjectorEntry | None) -> None:
        """Show the ceiling projector: its frame with axes at the mount (T_world_projector, the
        pan-tilt base) and, with a spot, its beam from the mount to that floor point; None
        removes it. Raises
        InvalidInput (nothing changes) for a pose that is not rigid or a bad spot."""
        view = None if projector is None else parse_projector(projector)
        with self._cond:
            self._projector = view
            self._dirty_navigation = True
            self._cond.notify_all()

    # -- what is drawn -----------------------------------------------------------------------

    def planned_path(self) -> np.ndarray:
        """Return the planned path as currently drawn, (N, 2) m (N = 0: none)."""
        with self._cond:
            return self._drawn_path.copy()

    def projector(self) -> ProjectorView | None:
        """Return the projector as currently drawn, or None."""
        with self._cond:
            return self._drawn_projector

    # -- drawing (worker thread) -------------------------------------------------------------

    def _draw_navigation(self, path: np.ndarray, projector: ProjectorView | None) -> None:
        server = self._server
        if server is None:
            return
        with server.atomic():
            server.scene.remove_by_name("/navigation/path")
            if len(path) >= 2:
                segments = np.stack([path[:-1], path[1:]], axis=1)  # (N - 1, 2, 2)
                height = np.full((len(segments), 2, 1), _PATH_HEIGHT)
                server.scene.add_line_segments(
                    "/navigation/path",
                    points=np.concatenate([segments, height], axis=2),
                    colors=_COLOR_PATH,
                    thickness=4.0,
                    thickness_units="screen",
                )
            server.scene.remove_by_name("/navigation/projector")
            server.scene.remove_by_name("/navigation/beam")
            if projector is not None:
                pose = projector.pose
                server.scene.add_frame(
                    "/navigation/projector",
                    wxyz=pose.wxyz,
                    position=pose.position,
                    axes_length=0.25,
                    axes_radius=0.012,
                )
                server.scene.add_label(
                    "/navigation/projector/label", projector.name, position=(0.0, 0.0, 0.1)
                )
                if projector.spot is not None:
                    beam = np.array([[pose.position, (*projector.spot, 0.0)]], dtype=np.float64)
                    server.scene.add_line_segments(
                        "/navigation/beam",
                        points=beam,
                        colors=_COLOR_BEAM,
                        thickness=2.0,
                        thickness_units="screen",
                    )
        with self._cond:
            self._drawn_path = path
            self._drawn_projector = projector
