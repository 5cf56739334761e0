"""The floor plan in the live scene: a grid under the whole plan, and each room as its walls,
a filled floor and its name at its centroid; the viewers' first camera frames the plan.

`FloorLayer` is the part of SceneService that holds and draws the floor plan; it uses the
service's lock (`_cond`).
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from core.geometry.polygon import area_centroid
from server.scene._entries import RoomEntry
from server.scene._geometry import as_polygon, triangulate_polygon

_COLOR_WALL = (51, 65, 85)
_ROOM_FILLS = ((191, 219, 254), (187, 247, 208), (254, 215, 170), (233, 213, 255), (254, 202, 202))


@dataclass(frozen=True)
class RoomView:
    """How one room is drawn: scene node, polygon (m, floor Z = 0) and label."""

    id: int
    name: str
    node: str
    polygon: tuple[tuple[float, float], ...]


def parse_rooms(rooms: Sequence[RoomEntry]) -> list[RoomView]:
    """Return the rooms as drawn; raise InvalidInput if a room has a bad polygon."""
    out = []
    for room in rooms:
        polygon = as_polygon(room.polygon, f"room {room.id} polygon")
        out.append(
            RoomView(
                id=room.id,
                name=room.name or f"room {room.id}",
                node=f"/floor/rooms/{room.id}",
                polygon=tuple((float(x), float(y)) for x, y in polygon),
            )
        )
    return out


class FloorLayer:
    """The floor plan of SceneService: thread-safe state changes, drawing on the scene's
    worker."""

    _cond: threading.Condition

    def _init_floor(self) -> None:
        self._rooms: list[RoomView] = []
        self._dirty_floor = True
        self._drawn_rooms: list[RoomView] = []  # read by rooms() under _cond

    def _restart_floor(self) -> None:
        """Under _cond, when the server (re)starts: the plan is to be drawn again."""
        self._dirty_floor = True

    def _floor_dirty(self) -> bool:
        return self._dirty_floor

    def _take_floor(self) -> tuple[bool, list[RoomView]]:
        """Under _cond: whether the plan changed since the last call, and its rooms."""
        dirty, self._dirty_floor = self._dirty_floor, False
        return dirty, list(self._rooms)

    def set_floor_plan(self, rooms: Sequence[RoomEntry]) -> None:
        """Replace the floor plan by `rooms` (their polygons [[x, y], ...] m).

        Raises InvalidInput (nothing changes) if a room has a bad polygon.
        """
        parsed = parse_rooms(rooms)
        with self._cond:
            self._rooms = parsed
            self._dirty_floor = True
            self._cond.notify_all()

    def rooms(self) -> list[RoomView]:
        """Return the rooms as currently drawn."""
        with self._cond:
            return list(self._drawn_rooms)

    def _draw_floor(self, server: Any, rooms: list[RoomView]) -> None:
        """Within the scene's atomic update: replace the plan drawn by `rooms`."""
        server.scene.remove_by_name("/floor")
        if rooms:
            pts = np.array([p for r in rooms for p in r.polygon])
            lo, hi = pts.min(axis=0) - 1.0, pts.max(axis=0) + 1.0
        else:
            lo, hi = np.array([-5.0, -5.0]), np.array([5.0, 5.0])
        lo, hi = np.floor(lo), np.ceil(hi)
        center = (hi + lo) / 2.0
        size = hi - lo
        server.scene.add_grid(
            "/floor/grid",
            width=float(size[0]),
            height=float(size[1]),
            plane="xy",
            cell_size=0.5,
            section_size=1.0,
            cell_color=(220, 224, 230),
            section_color=(170, 176, 186),
            position=(float(center[0]), float(center[1]), -0.002),
        )
        for i, room in enumerate(rooms):
            poly = np.array(room.polygon)
            n = len(poly)
            ring = np.stack([poly, np.roll(poly, -1, axis=0)], axis=1)  # (N, 2, 2)
            segments = np.concatenate([ring, np.full((n, 2, 1), 0.004)], axis=2)
            server.scene.add_line_segments(
                f"{room.node}/walls",
                points=segments,
                colors=_COLOR_WALL,
                thickness=3.0,
                thickness_units="screen",
            )
            server.scene.add_mesh_simple(
                f"{room.node}/fill",
                vertices=np.concatenate([poly, np.zeros((n, 1))], axis=1),
                faces=triangulate_polygon(poly),
                color=_ROOM_FILLS[i % len(_ROOM_FILLS)],
                flat_shading=True,
                side="double",
                cast_shadow=False,
                receive_shadow=False,
            )
            cx, cy = area_centroid(poly)
            server.scene.add_label(
                f"{room.node}/label",
                room.name,
                position=(float(cx), float(cy), 0.02),
                anchor="center-center",
            )
        # Frame the whole plan from a corner, a bit above; clients that connect later use this.
        span = float(max(size.max() - 2.0, 4.0))
        server.initial_camera.look_at = (float(center[0]), float(center[1]), 0.0)
        server.initial_camera.position = (
            float(center[0]) - 0.2 * span,
            float(center[1]) - 0.75 * span,
            0.65 * span,
        )
        server.initial_camera.up = (0.0, 0.0, 1.0)
        with self._cond:
            self._drawn_rooms = rooms
