"""Path planning on an occupancy grid: scikit-image's minimum-cost path, then line of sight.

Grid convention (`plan_path`): `free` (rows along y, columns along x, True = free, already
inflated by the robot's radius); cell (i, j) is the square of side `resolution` centred at
`origin + ((j + 0.5) resolution, (i + 0.5) resolution)`.

1. The 8-connected minimum-cost route between the start's and the goal's cells, by
   `skimage.graph.MCP_Geometric` (Dijkstra on the grid with diagonal steps costing sqrt 2).
   On a large grid the route is first found on a 4x coarser grid (a coarse cell is free when all
   its cells are), and the fine search is confined to a corridor around it; when the coarse grid
   closes a passage the fine search runs on the whole grid, so "no route" is always the fine
   grid's verdict.
2. Line-of-sight shortcutting ("string pulling", Botea et al. 2004's post-smoothing; Nash &
   Koenig 2013 review any-angle planners): from each vertex, jump to the farthest route cell it
   sees, found by an exponential then binary search along the route. Then, since a taut path
   bends only at obstacle corners (Lozano-Perez & Wesley 1979), the shortest path through the
   obstacles' convex corners (grid vertices) within 1.5 cells of that path, by Dijkstra on
   their visibility graph (scipy.sparse.csgraph): the taut path of the route's homotopy class.
   A segment "sees" when it stays in the closure of the free cells (`segment_is_free`), tested
   exactly piece by piece.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra
from skimage.graph import MCP_Geometric

from core.errors import IntspaceError, InvalidInput

Array = NDArray[np.float64]
BoolGrid = NDArray[np.bool_]

# Grids with more cells than this are searched coarse-to-fine (a 4x coarser route first).
_COARSE_ABOVE = 40_000
_COARSE = 4
_CORRIDOR = 3  # coarse cells on each side of the coarse route


class BlockedEndpoint(IntspaceError, ValueError):
    """The start or the goal lies in an obstacle (or its robot-radius margin) or off the grid."""


class NoRoute(IntspaceError, ValueError):
    """No collision-free route joins the start and the goal on the grid."""


@dataclass(frozen=True)
class GridRoute:
    """The raw 8-connected route: `cells` (K, 2) (row, col) from start to goal."""

    cells: NDArray[np.intp]


def _as_grid(free: ArrayLike) -> BoolGrid:
    g = np.asarray(free)
    if g.ndim != 2 or g.shape[0] < 1 or g.shape[1] < 1:
        raise InvalidInput(f"free must be a 2-D boolean grid (rows y, columns x), got {g.shape}")
    if g.dtype != np.bool_:
        raise InvalidInput(f"free must be boolean (True = free), got dtype {g.dtype}")
    return g


def _cell_of(free: BoolGrid, p: Array, origin: Array, res: float, name: str) -> tuple[int, int]:
    j = math.floor((p[0] - origin[0]) / res)
    i = math.floor((p[1] - origin[1]) / res)
    rows, cols = free.shape
    if not (0 <= i < rows and 0 <= j < cols):
        raise BlockedEndpoint(
            f"the {name} ({p[0]:.3f}, {p[1]:.3f}) m is off the grid (x {origin[0]:.3f}.."
            f"{origin[0] + cols * res:.3f}, y {origin[1]:.3f}..{origin[1] + rows * res:.3f} m)"
        )
    if not free[i, j]:
        raise BlockedEndpoint(
            f"the {name} ({p[0]:.3f}, {p[1]:.3f}) m lies in an obstacle or within the robot's "
            f"radius of one (cell row {i}, column {j}); move it into free floor"
        )
    return i, j


def _pieces(a: Array, b: Array) -> tuple[Array, NDArray[np.bool_]]:
    """Return the midpoints (M, 2) of the pieces the grid lines cut a -> b into, and whether
    each lies on a vertical / horizontal grid line (M, 2) (a piece running along a line)."""
    (x0, y0), (x1, y1) = a, b
    ts = [np.array([0.0, 1.0])]
    if x1 != x0:
        k = np.arange(math.ceil(min(x0, x1)), math.floor(max(x0, x1)) + 1, dtype=np.float64)
        ts.append((k - x0) / (x1 - x0))
    if y1 != y0:
        k = np.arange(math.ceil(min(y0, y1)), math.floor(max(y0, y1)) + 1, dtype=np.float64)
        ts.append((k - y0) / (y1 - y0))
    t = np.sort(np.clip(np.concatenate(ts), 0.0, 1.0))
    keep = np.diff(t) > 1e-12
    mid = 0.5 * (t[1:] + t[:-1])[keep] if np.any(keep) else np.array([0.5])
    m = a + mid[:, None] * (b - a)
    on_line = np.abs(m - np.round(m)) < 1e-9
    return m, on_line


def segment_is_free(free: BoolGrid, a: ArrayLike, b: ArrayLike) -> bool:
    """Return whether the segment a -> b (grid units: x = column, y = row; cell (i, j) is the
    square [j, j + 1] x [i, i + 1]) stays in the closure of the free cells: every piece between
    grid-line crossings lies in a free cell, or runs along a line beside one. Every point of a
    free cell clears the obstacles by the robot radius (see occupancy_grid), so touching a
    blocked cell's edge or corner is safe. Off the grid counts as blocked."""
    pa, pb = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    rows, cols = free.shape
    # Quick refusal: a sample of the segment strictly inside a blocked cell proves it blocked
    # (most segments a line-of-sight search tries are); only the rest get the exact walk.
    n = int(np.hypot(*(pb - pa)) * 2) + 2
    smp = pa + np.linspace(0.0, 1.0, n)[1:-1, None] * (pb - pa)
    fl = np.floor(smp)
    interior = np.all(np.abs(smp - np.round(smp)) > 1e-9, axis=1)
    ji, ii = fl[:, 0].astype(np.intp), fl[:, 1].astype(np.intp)
    inside = (ii >= 0) & (ii < rows) & (ji >= 0) & (ji < cols)
    if np.any(interior & ~inside):
        return False
    hit = interior & inside
    if not np.all(free[ii[hit], ji[hit]]):
        return False
    m, on = _pieces(pa, pb)
    j, i = np.floor(m[:, 0]).astype(np.intp), np.floor(m[:, 1]).astype(np.intp)
    inside = (i >= 0) & (i < rows) & (j >= 0) & (j < cols)
    ok = np.zeros(len(m), bool)
    ok[inside] = free[i[inside], j[inside]]
    edge = np.flatnonzero(~ok & np.any(on, axis=1))
    # A piece on a grid line is beside the two cells that share it: free if either is.
    for k in edge:
        for dx in (-0.5, 0.5) if on[k, 0] else (0.0,):
            for dy in (-0.5, 0.5) if on[k, 1] else (0.0,):
                jj, ii = math.floor(m[k, 0] + dx), math.floor(m[k, 1] + dy)
                if 0 <= ii < rows and 0 <= jj < cols and free[ii, jj]:
                    ok[k] = True
    return bool(np.all(ok))


def _route(costs: Array, start: tuple[int, int], goal: tuple[int, int]) -> NDArray[np.intp] | None:
    mcp = MCP_Geometric(costs, fully_connected=True)
    cum, _ = mcp.find_costs([start], [goal])
    if not np.isfinite(cum[goal]):
        return None
    return np.asarray(mcp.traceback(goal), dtype=np.intp)


def grid_route(free: BoolGrid, start: tuple[int, int], goal: tuple[int, int]) -> GridRoute | None:
    """Return the 8-connected minimum-length route between two free cells, or None."""
    costs = np.where(free, 1.0, np.inf)
    if free.size > _COARSE_ABOVE:
        f = _COARSE
        rows, cols = free.shape
        R, C = -(-rows // f), -(-cols // f)
        padded = np.zeros((R * f, C * f), bool)
        padded[:rows, :cols] = free
        coarse: BoolGrid = np.asarray(padded.reshape(R, f, C, f).all(axis=(1, 3)))
        cs, cg = (start[0] // f, start[1] // f), (goal[0] // f, goal[1] // f)
        coarse[cs] = coarse[cg] = True
        route = _route(np.where(coarse, 1.0, np.inf), cs, cg)
        if route is not None:
            band = np.zeros((R, C), bool)
            band[route[:, 0], route[:, 1]] = True
            # Dilate the coarse route into a corridor (separable max filter).
            for axis in (0, 1):
                b = band.copy()
                for k in range(1, _CORRIDOR + 1):
                    b |= np.roll(band, k, axis) | np.roll(band, -k, axis)
                band = b
            mask = np.repeat(np.repeat(band, f, 0), f, 1)[:rows, :cols] & free
            # Search only the corridor's bounding box: MCP's cost grows with the array.
            r = np.flatnonzero(mask.any(1))
            c = np.flatnonzero(mask.any(0))
            r0, r1, c0, c1 = r[0], r[-1] + 1, c[0], c[-1] + 1
            sub = np.where(mask[r0:r1, c0:c1], 1.0, np.inf)
            fine = _route(sub, (start[0] - r0, start[1] - c0), (goal[0] - r0, goal[1] - c0))
            if fine is not None:
                return GridRoute(fine + np.array([r0, c0]))
    fine = _route(costs, start, goal)
    return None if fine is None else GridRoute(fine)


def _farthest_visible(free: BoolGrid, pts: Array, i: int) -> int:
    """Return the largest k > i such that pts[i] sees pts[k], searching exponentially then by
    bisection (visibility along a route is, in practice, lost once and not regained)."""
    n = len(pts)
    lo, step = i + 1, 1
    while True:
        k = min(i + 2 * step, n - 1)
        if k <= lo or not segment_is_free(free, pts[i], pts[k]):
            hi = k
            break
        lo = k
        if k == n - 1:
            return k
        step *= 2
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if segment_is_free(free, pts[i], pts[mid]):
            lo = mid
        else:
            hi = mid
    return lo


def _convex_corners(free: BoolGrid) -> Array:
    """Return the grid vertices (M, 2) (x, y grid units) that are convex corners of the
    blocked region: exactly one of their four cells blocked (off the grid counts as blocked).
    A shortest path among polygonal obstacles bends only at such corners (Lozano-Perez &
    Wesley 1979)."""
    b = np.pad(~free, 1, constant_values=True).astype(np.int8)
    count = b[:-1, :-1] + b[1:, :-1] + b[:-1, 1:] + b[1:, 1:]
    i, j = np.nonzero(count == 1)
    return np.column_stack([j, i]).astype(np.float64)


def _near(points: Array, path: Array, dist: float) -> NDArray[np.bool_]:
    a, b = path[:-1], path[1:]
    d = b - a
    L2 = np.maximum(np.sum(d * d, 1), 1e-300)
    t = np.clip(np.einsum("mkj,kj->mk", points[:, None] - a, d) / L2, 0.0, 1.0)
    foot = a + t[..., None] * d
    out: NDArray[np.bool_] = np.min(np.linalg.norm(points[:, None] - foot, axis=2), 1) <= dist
    return out


def _tighten(free: BoolGrid, path: Array, corners: Array) -> Array:
    """Return the shortest path from path[0] to path[-1] through the obstacles' convex corners
    within 1.5 cells of `path` (a local visibility graph, Dijkstra by scipy.sparse.csgraph),
    or `path` itself when that is shorter."""
    cand = corners[_near(corners, path, 1.5)] if len(corners) else corners
    nodes = np.vstack([path[:1], cand, path[-1:]])
    n = len(nodes)
    ii, jj = np.triu_indices(n, 1)
    vis = np.array([segment_is_free(free, nodes[a], nodes[b]) for a, b in zip(ii, jj, strict=True)])
    w = np.linalg.norm(nodes[jj[vis]] - nodes[ii[vis]], axis=1)
    graph = coo_matrix((w, (ii[vis], jj[vis])), shape=(n, n)).tocsr()
    dist, pred = dijkstra(graph, directed=False, indices=0, return_predecessors=True)
    if not np.isfinite(dist[n - 1]) or dist[n - 1] >= _length(path) - 1e-12:
        return path
    chain = [n - 1]
    while chain[-1] != 0:
        chain.append(int(pred[chain[-1]]))
    return nodes[chain[::-1]]


def _length(p: Array) -> float:
    return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))


def shortcut(free: BoolGrid, pts: Array) -> Array:
    """Return the route (K, 2) (grid units) pulled taut: line-of-sight shortcuts, then the
    shortest path through the obstacle corners beside it (`_tighten`)."""
    out = [0]
    i = 0
    while i < len(pts) - 1:
        i = _farthest_visible(free, pts, i)
        out.append(i)
    return _tighten(free, pts[out], _convex_corners(free))


def _unpinch(free: BoolGrid, cells: NDArray[np.intp]) -> NDArray[np.intp]:
    """Return the route with a free orthogonal neighbour inserted in every diagonal step that
    grazes a blocked cell's corner, so that consecutive route cells see each other."""
    step = np.diff(cells, axis=0)
    diag = np.flatnonzero(np.all(step != 0, axis=1))
    if len(diag) == 0:
        return cells
    a = cells[diag]
    via1 = np.column_stack([a[:, 0] + step[diag, 0], a[:, 1]])
    via2 = np.column_stack([a[:, 0], a[:, 1] + step[diag, 1]])
    f1, f2 = free[via1[:, 0], via1[:, 1]], free[via2[:, 0], via2[:, 1]]
    graze = ~(f1 & f2)
    # Where both neighbours are blocked the route squeezes between two cells meeting at a
    # corner; the inflation margin (half a cell's diagonal) still keeps the robot clear.
    via = np.where(f1[:, None], via1, via2)
    out: list[NDArray[np.intp]] = []
    prev = 0
    for k, (d, g) in enumerate(zip(diag, graze, strict=True)):
        out.extend(cells[prev : d + 1])
        if g and (f1[k] or f2[k]):
            out.append(via[k])
        prev = int(d) + 1
    out.extend(cells[prev:])
    return np.asarray(out, dtype=np.intp)


def plan_path(
    free: ArrayLike,
    start: ArrayLike,
    goal: ArrayLike,
    *,
    resolution: float,
    origin: ArrayLike = (0.0, 0.0),
) -> Array:
    """Return the planned path (N, 2), world (x, y) metres, from `start` to `goal`.

    free: boolean grid (rows along y, columns along x; True = free, already inflated); cell
    (i, j) centred at origin + ((j + 0.5) resolution, (i + 0.5) resolution). The path's first
    point is `start`, its last `goal`, its straight segments touch free cells only (module
    docstring for the search and the shortcutting). Raises BlockedEndpoint (start or goal in
    an obstacle or off the grid, naming which), NoRoute, InvalidInput.
    """
    g = _as_grid(free)
    if not (isinstance(resolution, (int, float)) and math.isfinite(resolution) and resolution > 0):
        raise InvalidInput(f"resolution must be a positive number of metres, got {resolution}")
    res = float(resolution)
    o = np.asarray(origin, dtype=np.float64)
    s = np.asarray(start, dtype=np.float64)
    t = np.asarray(goal, dtype=np.float64)
    for name, v in (("origin", o), ("start", s), ("goal", t)):
        if v.shape != (2,) or not np.all(np.isfinite(v)):
            raise InvalidInput(f"{name} must be a finite (x, y) pair in metres, got {v}")
    cs = _cell_of(g, s, o, res, "start")
    cg = _cell_of(g, t, o, res, "goal")
    ps, pg = (s - o) / res, (t - o) / res  # grid units (x = column, y = row)
    if cs == cg or segment_is_free(g, ps, pg):
        return np.vstack([s, t])
    route = grid_route(g, cs, cg)
    if route is None:
        raise NoRoute(
            f"no collision-free route from ({s[0]:.3f}, {s[1]:.3f}) to ({t[0]:.3f}, {t[1]:.3f}) "
            "m: they lie in parts of the floor no gap wide enough for the robot joins"
        )
    centres = _unpinch(g, route.cells)[:, ::-1].astype(np.float64) + 0.5
    pts = np.vstack([ps, centres[1:-1], pg]) if len(centres) > 2 else np.vstack([ps, pg])
    taut = shortcut(g, pts)
    out = taut * res + o
    out[0], out[-1] = s, t
    return out
