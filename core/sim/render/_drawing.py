"""The renderer's drawing primitives beyond its rasteriser: the projector's laser spot (red
light added to the ideal canvas where the camera sees it) and a box carrying a printed mark (its
faces that face the camera)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from core.errors import InvalidInput
from core.sim.render._camera import CameraModel
from core.sim.render._raster import Array, _shade, _Target
from core.sim.render._visibility import _in_image

# The laser spot: a red dot of this radius (m) on the floor, whose glare spans at least
# SPOT_GLARE_PX pixels (standard deviation of its Gaussian image) however far it is; its peak
# adds this much red light (the red channel saturates on a bright floor) and a little green.
SPOT_RADIUS = 0.004
SPOT_GLARE_PX = 1.2
_SPOT_RED = 300.0
_SPOT_GREEN = 10.0


def _draw_spot(tgt: _Target, cam: CameraModel, spot: ArrayLike) -> tuple[Array, bool]:
    """Add the laser spot's light to the ideal canvas where the camera sees it (in front,
    inside the image, not hidden by what is drawn so far by more than 1 cm); return its
    projection with distortion (2,) and whether it was seen. The blob is drawn on the canvas
    before the lens remap, so it is distorted like everything else."""
    X = np.asarray(spot, dtype=np.float64)
    if X.size != 3 or not np.all(np.isfinite(X)):
        raise InvalidInput(f"spot must be a finite world point (3,), got {spot!r}")
    X = X.reshape(1, 3)
    px = cam.project(X)[0]
    Pc = tgt.to_camera(X)[0]
    seen = bool(Pc[2] > tgt.near and _in_image(cam, px[None])[0])
    if seen:
        uv = tgt.to_pixels(Pc[None])[0]
        ui, vi = math.floor(uv[0] + 0.5), math.floor(uv[1] + 0.5)
        seen = 0 <= ui < tgt.w and 0 <= vi < tgt.h and Pc[2] <= tgt.depth[vi, ui] + 0.01
    if not seen:
        return px, False
    sigma = max(SPOT_GLARE_PX, float(tgt.K[0, 0]) * SPOT_RADIUS / 2 / float(Pc[2]))
    r = math.ceil(5 * sigma)
    x0, y0 = max(int(uv[0]) - r, 0), max(int(uv[1]) - r, 0)
    x1, y1 = min(int(uv[0]) + r + 1, tgt.w), min(int(uv[1]) + r + 1, tgt.h)
    yy, xx = np.mgrid[y0:y1, x0:x1]
    g = np.exp(-((xx - uv[0]) ** 2 + (yy - uv[1]) ** 2) / (2 * sigma**2))
    roi = tgt.img[y0:y1, x0:x1].astype(np.float32)
    roi[..., 2] += _SPOT_RED * g
    roi[..., 1] += _SPOT_GREEN * g
    tgt.img[y0:y1, x0:x1] = np.clip(np.rint(roi), 0, 255).astype(np.uint8)
    return px, True


# A box carrying a printed mark: cardboard sides, a white top around the print.
_BOX_SIDE = (176, 140, 98)
_BOX_TOP = (236, 236, 230)


def _draw_box(
    tgt: _Target, eye: Array, top_centre: Array, R: Array, size: tuple[float, float, float]
) -> None:
    """Draw the faces of a box that face the camera at `eye`: its top face centred at
    `top_centre`, edges along R's x and y columns, extending size[2] along R's z (behind the
    top). The top is drawn 0.5 mm behind `top_centre`, so a print on that plane wins the
    depth test."""
    sx, sy, sz = (float(v) for v in size)
    if not (sx > 0 and sy > 0 and sz > 0):
        raise InvalidInput(f"box must be three positive sizes in metres, got {size}")
    x, y, z = R[:, 0], R[:, 1], R[:, 2]
    c = top_centre + 5e-4 * z
    corners = np.array(
        [c + a * sx / 2 * x + b * sy / 2 * y for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    )
    bottom = corners + sz * z
    faces = [(corners, -z, _BOX_TOP)]
    for i in range(4):
        j = (i + 1) % 4
        side = np.array([corners[i], corners[j], bottom[j], bottom[i]])
        out = side.mean(0) - (c + sz / 2 * z)
        faces.append((side, out / np.linalg.norm(out), _BOX_SIDE))
    for poly, n, colour in faces:
        if float(n @ (eye - poly.mean(0))) > 0:
            tgt.fill(poly, _shade(colour, n))
