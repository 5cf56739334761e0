"""plan_path: collision-free, near the shortest any-angle path, typed errors."""

from __future__ import annotations

import itertools

import networkx as nx
import numpy as np
import pytest
from shapely.geometry import LineString, Point, Polygon, box
from shapely.ops import unary_union

from core.navigation import BlockedEndpoint, NoRoute, occupancy_grid, plan_path
from core.navigation._grid import wall_spans
from core.sim.scene import default_scene

RES = 0.1
# Obstacles as cell-aligned rectangles (x0, y0, x1, y1) metres on an 8 m x 6 m grid.
RECTS = [(1.0, 0.0, 1.5, 4.0), (3.0, 2.0, 3.5, 6.0), (5.0, 1.0, 6.5, 2.0), (5.5, 3.5, 6.0, 5.5)]


def _grid() -> np.ndarray:
    free = np.ones((60, 80), bool)
    for x0, y0, x1, y1 in RECTS:
        free[round(y0 / RES) : round(y1 / RES), round(x0 / RES) : round(x1 / RES)] = False
    return free


def _length(p: np.ndarray) -> float:
    return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))


def _visibility_shortest(region: Polygon, corners: list[tuple[float, float]], a, b) -> float:
    """Length of the shortest path inside `region` (its closure) from a to b: the shortest
    path in the visibility graph of a, b and the obstacles' corners (Lozano-Perez & Wesley
    1979), an independent reference for the any-angle optimum."""
    nodes = [tuple(a), tuple(b), *corners]
    g = nx.Graph()
    for u, v in itertools.combinations(nodes, 2):
        if region.covers(LineString([u, v])):
            g.add_edge(u, v, weight=float(np.hypot(u[0] - v[0], u[1] - v[1])))
    return float(nx.shortest_path_length(g, tuple(a), tuple(b), weight="weight"))


def _segments_free(free: np.ndarray, path: np.ndarray, res: float, origin) -> bool:
    # Independent of the planner's exact piece walk: sample every segment every 1/50 cell; a
    # sample is fine when a free cell's closure holds it (on a cell edge: either side).
    for p, q in itertools.pairwise(path):
        n = max(2, int(np.ceil(np.linalg.norm(q - p) / res * 50)))
        g = (p + np.linspace(0, 1, n)[:, None] * (q - p) - origin) / res
        ok = np.zeros(n, bool)
        for dx in (-1e-9, 1e-9):
            for dy in (-1e-9, 1e-9):
                j, i = np.floor(g[:, 0] + dx).astype(int), np.floor(g[:, 1] + dy).astype(int)
                on = (i >= 0) & (j >= 0) & (i < free.shape[0]) & (j < free.shape[1])
                hit = np.zeros(n, bool)
                hit[on] = free[i[on], j[on]]
                ok |= hit
        if not ok.all():
            return False
    return True


def test_paths_are_within_two_percent_of_the_any_angle_optimum() -> None:
    free = _grid()
    region = box(0, 0, 8, 6).difference(unary_union([box(*r) for r in RECTS]))
    corners = sorted({(x, y) for x0, y0, x1, y1 in RECTS for x in (x0, x1) for y in (y0, y1)})
    rng = np.random.default_rng(3)
    cells = np.argwhere(free)
    worst = 0.0
    for _ in range(12):
        a, b = (cells[rng.integers(len(cells))][::-1] + rng.uniform(0.1, 0.9, 2)) * RES, None
        b = (cells[rng.integers(len(cells))][::-1] + rng.uniform(0.1, 0.9, 2)) * RES
        path = plan_path(free, a, b, resolution=RES)
        np.testing.assert_allclose(path[[0, -1]], [a, b])
        assert _segments_free(free, path, RES, (0.0, 0.0))
        ratio = _length(path) / _visibility_shortest(region, corners, a, b)
        assert ratio >= 1.0 - 1e-9  # nothing beats the optimum: the reference is right
        worst = max(worst, ratio)
    assert worst <= 1.02


def test_default_home_paths_keep_the_robot_off_walls_and_furniture() -> None:
    scene = default_scene()
    radius = 0.2
    grid = occupancy_grid(scene, radius, 0.05)
    walls = [
        LineString([a, b]).buffer(w.thickness / 2, cap_style="flat")
        for w in scene.walls
        for a, b in wall_spans(w)
    ]
    furniture = []
    for f in scene.furniture:
        c, s = np.cos(f.yaw), np.sin(f.yaw)
        hx, hy = f.size[0] / 2, f.size[1] / 2
        pts = [
            (f.centre[0] + c * x - s * y, f.centre[1] + s * x + c * y)
            for x, y in ((-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy))
        ]
        furniture.append(Polygon(pts))
    obstacles = unary_union(walls + furniture)
    legs = [((1.0, 1.2), (7.2, 1.3)), ((0.6, 4.5), (5.5, 4.2)), ((3.5, 4.3), (0.7, 4.3))]
    for a, b in legs:
        path = plan_path(grid.free, a, b, resolution=grid.resolution, origin=grid.origin)
        assert _segments_free(grid.free, path, grid.resolution, grid.origin)
        # Against the plan itself (not the grid): the robot's disc clears every obstacle.
        assert LineString(path).distance(obstacles) >= radius - 1e-9
        # Through the doors: the kitchen and bedroom legs cross the dividing wall.
        assert _length(path) >= np.hypot(b[0] - a[0], b[1] - a[1]) - 1e-9


def test_blocked_endpoints_and_missing_routes_raise_by_name() -> None:
    free = _grid()
    with pytest.raises(BlockedEndpoint, match="the start"):
        plan_path(free, (1.2, 1.0), (7.0, 5.0), resolution=RES)
    with pytest.raises(BlockedEndpoint, match="the goal"):
        plan_path(free, (0.5, 1.0), (5.7, 4.0), resolution=RES)
    with pytest.raises(BlockedEndpoint, match="off the grid"):
        plan_path(free, (0.5, 1.0), (9.0, 1.0), resolution=RES)
    walled = free.copy()
    walled[:, 40] = False
    with pytest.raises(NoRoute, match="no collision-free route"):
        plan_path(walled, (0.5, 1.0), (7.0, 5.0), resolution=RES)
    # A closed door of the default home leaves the bedroom's goal unreachable by name too.
    assert Point(0.5, 1.0).within(box(0, 0, 8, 6))


def test_origin_and_resolution_place_the_grid() -> None:
    free = _grid()
    o = np.array([10.0, -5.0])
    a, b = np.array([0.5, 1.0]), np.array([7.0, 5.0])
    p0 = plan_path(free, a, b, resolution=RES)
    p1 = plan_path(free, a + o, b + o, resolution=RES, origin=tuple(o))
    np.testing.assert_allclose(p1, p0 + o, atol=1e-9)
