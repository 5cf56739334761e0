"""The coverage-and-accuracy map of a camera network over a floor rectangle.

For every cell centre of a grid at height h: which cameras see it (in front, inside the image,
`NetworkCamera.in_view`, and, given the home's walls and furniture, with a clear line of sight,
core.localization.occluders) and the Cramer-Rao standard deviation sqrt(trace CRB) of its
position from the cameras that see it (core.localization.bounds). It tells an installer where
the network is blind or weak, i.e. where to add or re-aim a camera; `CoverageMap.plan_image`
draws it as a floor plan with the walls and a colour scale.
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
from core.localization.occluders import Occluders, line_of_sight

Array = NDArray[np.float64]

# The floor plan image (plan_image), BGR.
_WALL_BGR = (255, 255, 255)
_FURNITURE_BGR = (80, 160, 255)
_ONE_CAMERA_BGR = (150, 150, 150)
_PANEL_BGR = (40, 40, 40)
_TEXT_BGR = (235, 235, 235)
_LEGEND_WIDTH = 200
_BAR_HEIGHT = 120
_FONT = cv2.FONT_HERSHEY_SIMPLEX


@dataclass(frozen=True)
class CoverageMap:
    """Camera count and CRB accuracy on a floor grid.

    `x` (nx,) and `y` (ny,) are the cell centres (metres); grids are indexed [iy, ix] (row = y),
    as an image of the floor seen from above with y growing down the rows. `n_cameras` (ny, nx)
    cameras seeing each cell; `crb_std` (ny, nx) metres, sqrt(trace CRB) with all those cameras
    (inf where none); `seen_by` (C, ny, nx) which camera sees which cell: it images the cell
    and, when the map was made with occluders, nothing stands between them. `in_view`
    (C, ny, nx) which camera images it regardless of occluders (None: same as seen_by);
    `occluders` those the map honoured; `x_range`, `y_range` the rectangle.
    """

    x: Array
    y: Array
    height: float
    pixel_sigma: float
    n_cameras: NDArray[np.int64]
    crb_std: Array
    seen_by: NDArray[np.bool_] = field(repr=False)
    camera_names: tuple[str, ...] = ()
    in_view: NDArray[np.bool_] | None = field(default=None, repr=False)
    occluders: Occluders | None = field(default=None, repr=False)
    x_range: tuple[float, float] | None = None
    y_range: tuple[float, float] | None = None

    def fraction_covered(self, min_cameras: int = 1) -> float:
        """Return the fraction of cells seen by at least `min_cameras` cameras."""
        return float(np.mean(self.n_cameras >= min_cameras))

    def fraction_hidden(self) -> float:
        """Return the fraction of the (camera, cell) pairs in a camera's image that an occluder
        hides from it (0 without occluders, or when no camera images any cell)."""
        if self.in_view is None:
            return 0.0
        n_view = int(np.count_nonzero(self.in_view))
        if n_view == 0:
            return 0.0
        return float(np.count_nonzero(self.in_view & ~self.seen_by)) / n_view

    def scale_top(self) -> float:
        """Return the default upper end of the colour scale, metres: the 95th percentile of the
        finite std rounded up to 1, 2, 2.5 or 5 times a power of ten (as the dashboard does),
        so that a few far cells seen by one camera do not wash out the rest of the map."""
        std = self.crb_std[np.isfinite(self.crb_std) & (self.crb_std > 0)]
        if std.size == 0:
            return 0.01
        p95 = float(np.percentile(std, 95))
        mag = 10.0 ** math.floor(math.log10(p95))
        return next(
            (m * mag for m in (1.0, 2.0, 2.5, 5.0) if m * mag >= p95 * (1 - 1e-12)), 10 * mag
        )

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

    def plan_image(
        self, scale: int = 8, max_std: float | None = None, legend: bool = True
    ) -> NDArray[np.uint8]:
        """Return the map as a floor plan, a BGR image, with its walls and a colour scale.

        The map fills the top-left (ny * scale, nx * scale) pixels, +y pointing up as on a plan:
        cell (iy, ix) is the block of rows (ny - 1 - iy) * scale.. and columns ix * scale...
        Colours are `heatmap(max_std)` (default top: `scale_top()`); cells seen by exactly one
        camera carry a grey dot (no redundancy, a monocular fix). On top, the occluders' floor
        plan: the footprints of wall parts that reach down to the map's plane (so doors show
        as gaps) filled white, furniture outlined in orange. With `legend`, a panel of
        200 pixels on the right holds the colour scale (CRB std, metres, bright = accurate)
        and the meaning of the marks.
        """
        s = int(scale)
        if s < 1:
            raise InvalidInput(f"scale must be a positive number of pixels per cell, got {scale}")
        top = self.scale_top() if max_std is None else float(max_std)
        if not (math.isfinite(top) and top > 0):
            raise InvalidInput(f"max_std must be a positive number of metres, got {max_std}")
        ny, nx = self.crb_std.shape
        w, h = nx * s, ny * s
        heat: NDArray[np.uint8] = np.ascontiguousarray(
            cv2.resize(self.heatmap(top)[::-1], (w, h), interpolation=cv2.INTER_NEAREST),
            dtype=np.uint8,
        )
        if s >= 4:
            # A disc stamped in every one-camera cell, by broadcasting rather than a draw call
            # per cell (a map may have a million cells).
            c = np.arange(s) - (s - 1) / 2
            disc = c[:, None] ** 2 + c[None, :] ** 2 <= max(1.0, s / 6) ** 2
            one = self.n_cameras[::-1] == 1
            dots = (one[:, None, :, None] & disc[None, :, None, :]).reshape(h, w)
            heat[dots] = _ONE_CAMERA_BGR
        self._draw_occluders(heat)
        if not legend:
            return heat
        panel = self._legend(top)
        height = max(h, panel.shape[0])
        img = np.empty((height, w + panel.shape[1], 3), np.uint8)
        img[:] = _PANEL_BGR
        img[:h, :w] = heat
        img[: panel.shape[0], w:] = panel
        return img

    def _bounds(self) -> tuple[float, float, float, float]:
        def edges(c: Array, given: tuple[float, float] | None) -> tuple[float, float]:
            if given is not None:
                return given
            half = (c[1] - c[0]) / 2 if c.size > 1 else 0.5
            return float(c[0] - half), float(c[-1] + half)

        x0, x1 = edges(self.x, self.x_range)
        y0, y1 = edges(self.y, self.y_range)
        return x0, x1, y0, y1

    def _draw_occluders(self, img: NDArray[np.uint8]) -> None:
        occ = self.occluders
        if occ is None or len(occ) == 0:
            return
        x0, x1, y0, y1 = self._bounds()
        h, w = img.shape[:2]
        corners = occ.footprints()
        # Pixel centres at integers, 4 fractional bits for cv2's sub-pixel drawing.
        u = (corners[..., 0] - x0) / (x1 - x0) * w - 0.5
        v = (y1 - corners[..., 1]) / (y1 - y0) * h - 0.5
        pts = np.rint(np.stack([u, v], -1) * 16).astype(np.int32)
        walls = [
            pts[i]
            for i in range(len(occ))
            if occ.kinds[i] == "wall" and occ.z[i, 0] <= self.height + 1e-9
        ]
        furniture = [pts[i] for i in range(len(occ)) if occ.kinds[i] == "furniture"]
        if furniture:
            cv2.polylines(img, furniture, True, _FURNITURE_BGR, 1, cv2.LINE_8, 4)
        if walls:
            cv2.fillPoly(img, walls, _WALL_BGR, cv2.LINE_8, 4)
            cv2.polylines(img, walls, True, _WALL_BGR, 1, cv2.LINE_8, 4)

    def _legend(self, top: float) -> NDArray[np.uint8]:
        rows = [
            ("no camera", "black"),
            ("1 camera only", "dot"),
            ("2+ cameras", "plain"),
            ("wall", "wall"),
            ("furniture", "furniture"),
        ]
        bar_y = 48
        height = bar_y + _BAR_HEIGHT + 16 + 20 * len(rows)
        img = np.empty((height, _LEGEND_WIDTH, 3), np.uint8)
        img[:] = _PANEL_BGR

        def text(t: str, x: int, y: int) -> None:
            cv2.putText(img, t, (x, y), _FONT, 0.4, _TEXT_BGR, 1, cv2.LINE_AA)

        text("CRB std (m)", 10, 16)
        text(f"sigma {self.pixel_sigma:g} px, Z {self.height:g} m", 10, 34)
        level = np.rint(255.0 * (1.0 - np.arange(_BAR_HEIGHT) / (_BAR_HEIGHT - 1)))
        bar = cv2.applyColorMap(level.astype(np.uint8)[:, None], cv2.COLORMAP_VIRIDIS)
        img[bar_y : bar_y + _BAR_HEIGHT, 12:32] = bar
        for k in range(5):
            y = bar_y + round(k * (_BAR_HEIGHT - 1) / 4)
            cv2.line(img, (32, y), (37, y), _TEXT_BGR, 1)
            label = f"{top * k / 4:.3g}"
            text((">= " if k == 4 else "") + label, 42, y + 4)
        y = bar_y + _BAR_HEIGHT + 16
        mid = tuple(int(c) for c in bar[_BAR_HEIGHT // 2, 0])
        for label, mark in rows:
            box = ((12, y), (32, y + 14))
            if mark == "black":
                cv2.rectangle(img, *box, (0, 0, 0), -1)
                cv2.rectangle(img, *box, (90, 90, 90), 1)
            elif mark in ("dot", "plain"):
                cv2.rectangle(img, *box, mid, -1)
                if mark == "dot":
                    cv2.circle(img, (22, y + 7), 2, _ONE_CAMERA_BGR, -1)
            elif mark == "wall":
                cv2.rectangle(img, (12, y + 4), (32, y + 10), _WALL_BGR, -1)
            else:
                cv2.rectangle(img, *box, _FURNITURE_BGR, 1)
            text(label, 42, y + 11)
            y += 20
        return img

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
            "fraction_hidden": self.fraction_hidden(),
            "occluders": [] if self.occluders is None else self.occluders.to_list(),
        }


def coverage_map(
    cameras: Sequence[NetworkCamera],
    x_range: tuple[float, float],
    y_range: tuple[float, float],
    *,
    spacing: float = 0.1,
    height: float = 0.0,
    pixel_sigma: float = 1.0,
    occluders: Occluders | None = None,
    occlusion_tolerance: float = 0.005,
) -> CoverageMap:
    """Return the coverage-and-accuracy map over [x0, x1] x [y0, y1] at Z = height.

    The rectangle is cut into round((x1 - x0) / spacing) x round((y1 - y0) / spacing) equal cells
    (at least one each way); values are taken at the cell centres. pixel_sigma: the detection
    noise (px) the CRB assumes. occluders: the walls and furniture; a camera then counts for a
    cell only if the segment from its optical centre to the cell's point at Z = height crosses
    none of them (`line_of_sight` with `occlusion_tolerance` metres), and the CRB uses only
    those cameras. Vectorised over all cells; the cost is a projection and a 2 x 2 Jacobian per
    camera and cell, and a segment-box test per camera, cell and occluder (about 0.05 s for four
    cameras, 22 boxes and 4,800 cells).
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
    if occluders is not None and not isinstance(occluders, Occluders):
        raise InvalidInput(
            f"occluders must be core.localization.occluders.Occluders, got {type(occluders)}"
        )
    x = x0 + (np.arange(nx) + 0.5) * (x1 - x0) / nx
    y = y0 + (np.arange(ny) + 0.5) * (y1 - y0) / ny
    gx, gy = np.meshgrid(x, y)
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    X = np.column_stack([xy, np.full(len(xy), h)])
    in_view = np.stack([c.in_view(X) for c in cams])
    seen = in_view
    if occluders is not None and len(occluders) > 0:
        centres = np.stack([c.center for c in cams])
        seen = in_view & line_of_sight(centres, X, occluders, tolerance=occlusion_tolerance)
    bound = cramer_rao_bound(cams, xy, h, pixel_sigma=pixel_sigma, visible=seen)
    return CoverageMap(
        x=x,
        y=y,
        height=h,
        pixel_sigma=float(pixel_sigma),
        n_cameras=bound.n_cameras.reshape(ny, nx),
        crb_std=bound.std.reshape(ny, nx),
        seen_by=bound.visible.reshape(len(cams), ny, nx),
        camera_names=tuple(c.name for c in cams),
        in_view=in_view.reshape(len(cams), ny, nx) if occluders is not None else None,
        occluders=occluders,
        x_range=(x0, x1),
        y_range=(y0, y1),
    )
