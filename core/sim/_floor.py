"""The free floor of a scene: where the robot can stand, and shortest paths between stops."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from core.errors import InvalidInput
from core.geometry.polygon import inside_polygon as inside
from core.sim.scene import Scene, Wall

Array = NDArray[np.float64]


def _solid_spans(w: Wall, doors: bool) -> list[tuple[Array, Array]]:
    """Return the wall's solid segments (start, end): the whole wall, or the pieces between
    its door openings."""
    a, b = np.array(w.start), np.array(w.end)
    if not doors or not w.doors:
        return [(a, b)]
    length = float(np.linalg.norm(b - a))
    d = (b - a) / length
    cuts = [0.0]
    for door in sorted(w.doors, key=lambda x: x.offset):
        cuts += [door.offset, door.offset + door.width]
    cuts.append(length)
    return [
        (a + d * s0, a + d * s1) for s0, s1 in zip(cuts[::2], cuts[1::2], strict=True) if s1 > s0
    ]


def free_floor_grid(
    scene: Scene, spacing: float, clearance: float, *, through_doors: bool = False
) -> Array:
    """Return floor points (N, 2) on a grid of `spacing` metres inside the rooms, at least
    `clearance` metres from every wall (its door openings left open with `through_doors`) and
    furniture footprint (robot radius plus margin)."""
    rooms = np.array([p for r in scene.rooms for p in r.polygon])
    lo, hi = rooms.min(0), rooms.max(0)
    gx = np.arange(lo[0] + spacing / 2, hi[0], spacing)
    gy = np.arange(lo[1] + spacing / 2, hi[1], spacing)
    P = np.stack(np.meshgrid(gx, gy), -1).reshape(-1, 2)
    ok = np.zeros(len(P), bool)
    for room in scene.rooms:
        ok |= inside(P, np.array(room.polygon))
    for w in scene.walls:
        for a, b in _solid_spans(w, through_doors):
            d = b - a
            s = np.clip((P - a) @ d / (d @ d), 0, 1)
            ok &= np.linalg.norm(P - (a + s[:, None] * d), axis=1) > clearance + w.thickness / 2
    for f in scene.furniture:
        c, s_ = math.cos(f.yaw), math.sin(f.yaw)
        q = (P - np.array(f.centre)) @ np.array([[c, -s_], [s_, c]])
        half = np.array(f.size[:2]) / 2 + clearance
        ok &= ~np.all(np.abs(q) < half, axis=1)
    return P[ok]


class FloorRoutes:
    """Shortest paths over the free floor (through doors) between any two floor points, on
    an 8-connected grid of `spacing` metres (Dijkstra), simplified to the grid points where
    the path turns."""

    def __init__(self, scene: Scene, clearance: float, spacing: float = 0.1) -> None:
        self.points = free_floor_grid(scene, spacing, clearance, through_doors=True)
        if len(self.points) == 0:
            raise InvalidInput("the scene has no free floor for the robot to drive on")
        ij = np.rint(self.points / spacing - 0.5).astype(np.int64)
        index = {(int(i), int(j)): k for k, (i, j) in enumerate(ij)}
        rows, cols, cost = [], [], []
        for di, dj in ((1, 0), (0, 1), (1, 1), (1, -1)):
            for k, (i, j) in enumerate(ij):
                n = index.get((int(i + di), int(j + dj)))
                if n is not None:
                    rows.append(k)
                    cols.append(n)
                    cost.append(spacing * math.hypot(di, dj))
        n = len(self.points)
        self.graph = coo_matrix((cost, (rows, cols)), shape=(n, n)).tocsr()

    def nearest(self, xy: Array) -> int:
        """Return the index of the free grid point nearest to xy (2,)."""
        return int(np.argmin(np.sum((self.points - xy) ** 2, axis=1)))

    def path(self, a: Array, b: Array) -> Array:
        """Return waypoints (K, 2) from near a to b over the free floor, ending at b (the
        grid points where the shortest path changes direction, then b); just [b] when no
        path exists (the robot then heads straight for it)."""
        ia, ib = self.nearest(a), self.nearest(b)
        _, pred = dijkstra(self.graph, directed=False, indices=ia, return_predecessors=True)
        if ib != ia and pred[ib] < 0:
            return np.asarray(b, dtype=np.float64).reshape(1, 2)
        chain = [ib]
        while chain[-1] != ia:
            chain.append(int(pred[chain[-1]]))
        pts = self.points[chain[::-1]]
        if len(pts) > 2:
            d = np.diff(pts, axis=0)
            turn = np.any(np.abs(d[1:] - d[:-1]) > 1e-9, axis=1)
            pts = np.vstack([pts[1:-1][turn], pts[-1:]])
        return np.vstack([pts[:-1], np.asarray(b, dtype=np.float64).reshape(1, 2)])
