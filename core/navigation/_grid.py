"""The occupancy grid of a floor plan, inflated by the robot's radius.

A floor plan is what an installer knows of a space: room polygons, walls (with door openings)
and furniture footprints. Any object with those fields works (`FloorPlan`); the twin's scene
(core.sim.scene.Scene) is one. A cell is free when it lies inside a room and every point of it
is at least `robot_radius` from every solid wall span (the wall's centre line widened by half its
thickness) and every furniture footprint: its centre clears them by robot_radius plus half the
cell's diagonal. So any segment through free cells keeps the robot's disc off the obstacles.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from core.geometry.polygon import inside_polygon

Array = NDArray[np.float64]


class _Room(Protocol):
    @property
    def polygon(self) -> Sequence[tuple[float, float]]: ...


class _Door(Protocol):
    @property
    def offset(self) -> float: ...
    @property
    def width(self) -> float: ...


class _Wall(Protocol):
    @property
    def start(self) -> tuple[float, float]: ...
    @property
    def end(self) -> tuple[float, float]: ...
    @property
    def thickness(self) -> float: ...
    @property
    def doors(self) -> Sequence[_Door]: ...


class _Furniture(Protocol):
    @property
    def centre(self) -> tuple[float, float]: ...
    @property
    def size(self) -> tuple[float, float, float]: ...
    @property
    def yaw(self) -> float: ...


class FloorPlan(Protocol):
    """Rooms (polygons), walls with doors and furniture boxes, as in core.sim.scene.Scene."""

    @property
    def rooms(self) -> Sequence[_Room]: ...
    @property
    def walls(self) -> Sequence[_Wall]: ...
    @property
    def furniture(self) -> Sequence[_Furniture]: ...


@dataclass(frozen=True)
class OccupancyGrid:
    """A boolean grid for `plan_path`: `free` (rows along y, columns along x), `resolution` m,
    `origin` (x, y) m of the grid's lower-left corner; cell (i, j) centred at
    origin + ((j + 0.5) resolution, (i + 0.5) resolution)."""

    free: NDArray[np.bool_]
    resolution: float
    origin: tuple[float, float]

    def centres(self) -> Array:
        """Return the cell centres (rows, cols, 2), world metres."""
        rows, cols = self.free.shape
        x = self.origin[0] + (np.arange(cols) + 0.5) * self.resolution
        y = self.origin[1] + (np.arange(rows) + 0.5) * self.resolution
        return np.stack(np.meshgrid(x, y), -1)


def _segment_distance(P: Array, a: Array, b: Array) -> Array:
    d = b - a
    s = np.clip((P - a) @ d / (d @ d), 0.0, 1.0)
    out: Array = np.linalg.norm(P - (a + s[:, None] * d), axis=1)
    return out


def wall_spans(wall: _Wall) -> list[tuple[Array, Array]]:
    """Return the solid spans (start, end) of a wall between its door openings."""
    a, b = np.asarray(wall.start, np.float64), np.asarray(wall.end, np.float64)
    length = float(np.linalg.norm(b - a))
    u = (b - a) / length
    spans, pos = [], 0.0
    for door in sorted(wall.doors, key=lambda d: d.offset):
        if door.offset > pos:
            spans.append((a + u * pos, a + u * door.offset))
        pos = max(pos, door.offset + door.width)
    if pos < length:
        spans.append((a + u * pos, b))
    return spans


def occupancy_grid(plan: FloorPlan, robot_radius: float, resolution: float = 0.05) -> OccupancyGrid:
    """Return the inflated occupancy grid of a floor plan (module docstring for the rule).

    robot_radius: metres (the disc that must clear obstacles); resolution: cell side, metres.
    The grid covers the rooms' bounding box. Raises InvalidInput for non-positive sizes or a
    plan without rooms.
    """
    if not (math.isfinite(robot_radius) and robot_radius >= 0):
        raise InvalidInput(f"robot_radius must be >= 0 metres, got {robot_radius}")
    if not (math.isfinite(resolution) and resolution > 0):
        raise InvalidInput(f"resolution must be a positive number of metres, got {resolution}")
    if not plan.rooms:
        raise InvalidInput("the floor plan has no rooms; give at least one room polygon")
    corners = np.array([p for r in plan.rooms for p in r.polygon], dtype=np.float64)
    lo, hi = corners.min(0), corners.max(0)
    cols = max(1, math.ceil((hi[0] - lo[0]) / resolution - 1e-9))
    rows = max(1, math.ceil((hi[1] - lo[1]) / resolution - 1e-9))
    grid = OccupancyGrid(np.zeros((rows, cols), bool), resolution, (float(lo[0]), float(lo[1])))
    P = grid.centres().reshape(-1, 2)
    clear = robot_radius + resolution * math.sqrt(0.5)
    ok = np.zeros(len(P), bool)
    for room in plan.rooms:
        ok |= inside_polygon(P, np.asarray(room.polygon, dtype=np.float64))
    for w in plan.walls:
        for a, b in wall_spans(w):
            ok &= _segment_distance(P, a, b) >= clear + w.thickness / 2
    for f in plan.furniture:
        c, s = math.cos(f.yaw), math.sin(f.yaw)
        q = (P - np.asarray(f.centre)) @ np.array([[c, -s], [s, c]])
        # Distance to the footprint rectangle (zero inside).
        excess = np.maximum(np.abs(q) - np.asarray(f.size[:2]) / 2, 0.0)
        ok &= np.linalg.norm(excess, axis=1) >= clear
    return OccupancyGrid(ok.reshape(rows, cols), resolution, grid.origin)
