"""The coverage-and-accuracy map of a camera network over a floor rectangle.

For every cell centre of a grid at height h: which cameras image it (in front, inside the image,
`NetworkCamera.in_view`) and the Cramer-Rao standard deviation sqrt(trace CRB) of its position
from all of them (core.localization.bounds). It tells an installer where the network is blind
or weak, i.e. where to add or re-aim a camera.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from core.localization._checks import as_cameras, check_height
from core.localization.bounds import cramer_rao_bound
from core.localization.cameras import NetworkCamera

Array = NDArray[np.float64]


@dataclass(frozen=True)
class CoverageMap:
    """Camera count and CRB accuracy on a floor grid.

    `x` (nx,) and `y` (ny,) are the cell centres (metres); grids are indexed [iy, ix] (row = y),
    as an image of the floor seen from above with y growing down the rows. `n_cameras` (ny, nx)
    cameras imaging each cell; `crb_std` (ny, nx) metres, sqrt(trace CRB) with all those cameras
    (inf where none); `seen_by` (C, ny, nx) which camera sees which cell.
    """

    x: Array
    y: Array
    height: float
    pixel_sigma: float
    n_cameras: NDArray[np.int64]
    crb_std: Array
    seen_by: NDArray[np.bool_] = field(repr=False)
    camera_names: tuple[str, ...] = ()

    def fraction_covered(self, min_cameras: int = 1) -> float:
        """Return the fraction of cells seen by at least `min_cameras` cameras."""
        return float(np.mean(self.n_cameras >= min_cameras))

    def heatmap(self, max_std: float | None = None) -> NDArray[np.uint8]:
        """Return a BGR heat map (ny, nx, 3) of `crb_std`, row i for y[i], column j for x[j].

        Colour map viridis, bright = accurate: std 0 is yellow, `max_std` (default: the largest
        finite std) and worse is dark blue; cells no camera sees are black. Scale it up with
        cv2.resize(..., interpolation=cv2.INTER_NEAREST) to draw it.
        """
        std = self.crb_std
        seen = np.isfinite(std)
        top = float(np.max(std[seen], initial=0.0)) if max_std is None else float(max_std)
        if not top > 0:
            top = 1.0
        level = np.zeros(std.shape, dtype=np.uint8)
        level[seen] = np.round(255.0 * (1.0 - np.clip(std[seen] / top, 0.0, 1.0)))
        img = cv2.applyColorMap(level, cv2.COLORMAP_VIRIDIS)
        img[~seen] = 0
        return np.asarray(img, dtype=np.uint8)

    def to_dict(self) -> dict[str, Any]:
        """Return a JSON-ready description (lists; unseen cells' std as None)."""
        std = [[None if not math.isfinite(v) else float(v) for v in row] for row in self.crb_std]
        return {
            "x": self.x.tolist(),
            "y": self.y.tolist(),
            "height": self.height,
            "pixel_sigma": self.pixel_sigma,
            "n_cameras": self.n_cameras.tolist(),
            "crb_std": std,
            "cameras": list(self.camera_names),
            "seen_by": self.seen_by.tolist(),
        }


def coverage_map(
    cameras: Sequence[NetworkCamera],
    x_range: tuple[float, float],
    y_range: tuple[float, float],
    *,
    spacing: float = 0.1,
    height: float = 0.0,
    pixel_sigma: float = 1.0,
) -> CoverageMap:
    """Return the coverage-and-accuracy map over [x0, x1] x [y0, y1] at Z = height.

    The rectangle is cut into round((x1 - x0) / spacing) x round((y1 - y0) / spacing) equal cells
    (at least one each way); values are taken at the cell centres. pixel_sigma: the detection
    noise (px) the CRB assumes. Vectorised over all cells; the cost is a projection and a 2 x 2
    Jacobian per camera and cell.
    """
    cams = as_cameras(cameras)
    h = check_height(height)
    try:
        x0, x1 = (float(v) for v in x_range)
        y0, y1 = (float(v) for v in y_range)
        step = float(spacing)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"x_range and y_range must be (min, max) pairs: {exc}") from None
    if not all(math.isfinite(v) for v in (x0, x1, y0, y1, step)) or x1 <= x0 or y1 <= y0:
        raise InvalidInput(f"the rectangle must be finite with min < max, got {x_range}, {y_range}")
    if step <= 0:
        raise InvalidInput(f"spacing must be positive metres, got {spacing}")
    nx = max(1, round((x1 - x0) / step))
    ny = max(1, round((y1 - y0) / step))
    if nx * ny > 10_000_000:
        raise InvalidInput(f"{nx} x {ny} cells is too many; use a larger spacing")
    x = x0 + (np.arange(nx) + 0.5) * (x1 - x0) / nx
    y = y0 + (np.arange(ny) + 0.5) * (y1 - y0) / ny
    gx, gy = np.meshgrid(x, y)
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    bound = cramer_rao_bound(cams, xy, h, pixel_sigma=pixel_sigma)
    return CoverageMap(
        x=x,
        y=y,
        height=h,
        pixel_sigma=float(pixel_sigma),
        n_cameras=bound.n_cameras.reshape(ny, nx),
        crb_std=bound.std.reshape(ny, nx),
        seen_by=bound.visible.reshape(len(cams), ny, nx),
        camera_names=tuple(c.name for c in cams),
    )
