"""Collision-free routes for the robot's round base on the floor plan (walls, doors, furniture
footprints; a prior, like the installer's plan, never the twin's truth): two occupancy grids
(core.navigation) inflated by the base radius and PLAN_MARGIN (where the base may stand) or
TRANSIT_MARGIN (what routes keep to where the floor allows), and routes planned on them with
straight legs in and out of a grid's margin (`FloorRoutes.route`)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from core.navigation import (
    BlockedEndpoint,
    OccupancyGrid,
    occupancy_grid,
    plan_path,
    segment_is_free,
)
from core.navigation import NoRoute as NoPath
from core.sim.scene import Scene

Array = NDArray[np.float64]

PLAN_RESOLUTION = 0.05  # m: the occupancy grid's cell
PLAN_MARGIN = 0.05  # m beyond the base radius where the base may stand (reading poses)
# m beyond the base radius along routes: the pose estimate drifts by several centimetres
# between two signposts (10 cm measured in the survey), so routes keep off obstacles by more
# where the floor allows (where it does not, routes fall back to PLAN_MARGIN).
TRANSIT_MARGIN = 0.15


class FloorRoutes:
    """The floor plan as the base's map: `grid` (where the base may stand) and `transit` (the
    cells routes keep to where they can)."""

    def __init__(self, scene: Scene, base_radius: float) -> None:
        self.grid: OccupancyGrid = occupancy_grid(scene, base_radius + PLAN_MARGIN, PLAN_RESOLUTION)
        self.transit: OccupancyGrid = occupancy_grid(
            scene, base_radius + TRANSIT_MARGIN, PLAN_RESOLUTION
        )

    def free(self, p: Array, grid: OccupancyGrid | None = None) -> bool:
        """Return whether the world point p (x, y) lies in a free cell of `grid` (default: the
        grid of where the base may stand)."""
        g = self.grid if grid is None else grid
        j = int(np.floor((p[0] - g.origin[0]) / g.resolution))
        i = int(np.floor((p[1] - g.origin[1]) / g.resolution))
        rows, cols = g.free.shape
        return bool(0 <= i < rows and 0 <= j < cols and g.free[i, j])

    def sees(self, a: Array, b: Array) -> bool:
        """Return whether the straight segment a -> b (world x, y) stays in free cells."""
        o = np.asarray(self.grid.origin)
        r = self.grid.resolution
        return segment_is_free(self.grid.free, (a - o) / r, (b - o) / r)

    @staticmethod
    def nearest_free(g: OccupancyGrid, p: Array, within: float = 0.5) -> Array | None:
        """Return the centre of the free cell of `g` nearest the world point p (x, y) within
        `within` metres, or None."""
        c = g.centres()[g.free]
        if len(c) == 0:
            return None
        d = np.linalg.norm(c - p, axis=1)
        k = int(np.argmin(d))
        return c[k] if d[k] <= within else None

    def route_on(self, g: OccupancyGrid, a: Array, b: Array) -> Array | None:
        """Return the route (N, 2) from a to b on grid g, with straight legs from a to g's
        nearest free cell and from g's nearest free cell to b when they lie in its margin
        (None when there is no route or those legs cross where the base may not stand)."""
        s = a if self.free(a, g) else self.nearest_free(g, a)
        t = b if self.free(b, g) else self.nearest_free(g, b)
        if s is None or t is None:
            return None
        try:
            route = plan_path(g.free, s, t, resolution=g.resolution, origin=g.origin)
        except (BlockedEndpoint, NoPath):
            return None
        if s is not a:
            # Out of the margin to its nearest free cell (short; checked on the floor where
            # the base may stand, unless it already stands in that margin too).
            if self.free(a) and not self.sees(a, s):
                return None
            route = np.vstack([a, route])
        if t is not b:
            if not self.sees(t, b):
                return None
            route = np.vstack([route, b])
        return route

    def route(self, here: Array, goal: Array) -> Array | None:
        """Return a collision-free route (N, 2), world (x, y), from `here` to `goal` (moved to
        the nearest cell where the base may stand when it lies in an obstacle's margin): on
        the grid inflated by TRANSIT_MARGIN where the floor allows, else on the one inflated
        by PLAN_MARGIN (legs in and out of a grid's margin straight; `route_on`), or None when
        there is none."""
        if not self.free(goal):
            near = self.nearest_free(self.grid, goal)
            if near is None:
                return None
            goal = near
        route = self.route_on(self.transit, here, goal)
        return route if route is not None else self.route_on(self.grid, here, goal)
