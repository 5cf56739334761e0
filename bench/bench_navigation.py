"""Path planning on a 400 x 300 grid: plan_path against scikit-image's raw route.

Run from the repository root: python -m bench.bench_navigation
The grid (0.05 m cells, 20 m x 15 m) holds 25 seeded rectangular obstacles; the start and goal
are opposite corners. Rows:
  * plan_path: the whole planner (coarse route, corridor route, line of sight, corner
    tightening) returning the any-angle path (goal: <= 50 ms, spec 03);
  * skimage route_through_array: the raw 8-connected minimum-cost route alone on the full
    grid (what plan_path builds on), the anchor of the ratio.
Columns: the path length in metres (the raw route's is its 8-connected length) and vertices.
"""

from __future__ import annotations

import numpy as np
from skimage.graph import route_through_array

from bench._common import best_of, print_table
from core.navigation import plan_path

RES = 0.05


def _grid(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    free = np.ones((300, 400), bool)
    for _ in range(25):
        x, y = rng.integers(0, 400), rng.integers(0, 300)
        w, h = rng.integers(5, 60, 2)
        free[y : y + h, x : x + w] = False
    free[:6, :6] = True
    free[-6:, -6:] = True
    return free


def main() -> None:
    free = _grid()
    start, goal = (0.1, 0.1), (19.9, 14.9)
    path = plan_path(free, start, goal, resolution=RES)
    t_plan = best_of(lambda: plan_path(free, start, goal, resolution=RES), repeats=15)
    costs = np.where(free, 1.0, np.inf)
    cells, _ = route_through_array(costs, (2, 2), (297, 397), geometric=True)
    t_raw = best_of(
        lambda: route_through_array(costs, (2, 2), (297, 397), geometric=True), repeats=15
    )
    c = np.asarray(cells, dtype=np.float64)[:, ::-1] * RES
    raw_len = float(np.sum(np.linalg.norm(np.diff(c, axis=0), axis=1)))
    plan_len = float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1)))
    print_table(
        "Planning on 400 x 300 cells (0.05 m), 25 obstacles, corner to corner",
        [
            ("plan_path", t_plan, {"length m": f"{plan_len:.3f}", "vertices": str(len(path))}),
            (
                "skimage route_through_array",
                t_raw,
                {"length m": f"{raw_len:.3f}", "vertices": str(len(cells))},
            ),
        ],
        anchor="skimage route_through_array",
    )
    print(f"goal: plan_path <= 50 ms: {'met' if t_plan <= 0.05 else 'NOT met'}")


if __name__ == "__main__":
    main()
