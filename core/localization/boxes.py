"""A detector's box as a floor measurement: the foot point (the box's bottom centre) with its
covariance, for the camera node and the service alike.

A person detector (the node's own, Frigate's, a user's) gives an axis-aligned box around a
person. A standing person's feet are at the bottom of the box, so the bottom centre is the image
of a point on the floor (height 0), which the tracker takes like any other pixel measurement
(core.localization.tracking). How well a box's bottom centre marks the feet grows with the box:
the legs' stride, the arms and a detector's jitter all scale with the person's image. The model
is

    sigma_u = max(K_U * w, FLOOR_PX),  sigma_v = max(K_V * h, FLOOR_PX)

for a box w x h pixels, uncorrelated. When a side of the box is cut by the image's edge or by a
mask, the box stops at the cut and not at the person:

* a cut bottom: the feet are not in the image, so the foot is not measured (`measured` False);
  the box can be stored, but it must not give a floor position;
* a cut left or right side: the centre moves by up to half the hidden width; sigma_u is raised
  to half the visible width, which covers a person whose hidden part is as wide as what shows;
* a cut top changes nothing at the feet.

The bottom centre is the body's near edge, not its centre: a body of radius r (BodyModel, an
adult's half shoulder width) stands with its axis r further from the camera, in plan, than the
point the box's bottom shows (the steepest ray grazes the base's nearest point; see
core.localization.detect.locate_body_axis). The tracker follows body axes, so that cameras on
opposite sides agree; `foot_on_axis` moves a camera's feet there, with r's spread added.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_points
from core.errors import InvalidInput
from core.geometry.camera import undistort_points
from core.localization._projection import distort_to_pixels, project_plane
from core.localization.cameras import NetworkCamera
from core.localization.ground import PointStatus, locate_monocular

Array = NDArray[np.float64]

# The sides of a box that can be cut, in the order of the `cut` mask's columns.
BOX_SIDES = ("bottom", "top", "left", "right")


@dataclass(frozen=True)
class BoxNoise:
    """The foot's standard deviation as fractions of the box's width (k_u) and height (k_v),
    never below floor_px (a detector's pixel quantisation and jitter on a small box)."""

    k_u: float = 0.10
    k_v: float = 0.04
    floor_px: float = 1.0


DEFAULT_BOX_NOISE = BoxNoise()


@dataclass(frozen=True)
class FootMeasurement:
    """Foot points of N boxes: pixel (N, 2) distorted px (the bottom centre), cov (N, 2, 2) px^2,
    measured (N,) bool, False where the box's bottom is cut (no floor position from it)."""

    pixel: Array
    cov: Array
    measured: NDArray[np.bool_]


def cut_mask(cuts: Iterable[Iterable[str]]) -> NDArray[np.bool_]:
    """Return the (N, 4) mask of cut sides (columns in BOX_SIDES order) of N lists of side
    names; an unknown name raises InvalidInput."""
    rows = []
    for i, sides in enumerate(cuts):
        row = [False] * len(BOX_SIDES)
        for side in sides:
            if side not in BOX_SIDES:
                raise InvalidInput(
                    f"box {i}: unknown cut side {side!r}; the sides are {', '.join(BOX_SIDES)}"
                )
            row[BOX_SIDES.index(side)] = True
        rows.append(row)
    return np.array(rows, dtype=bool).reshape(-1, len(BOX_SIDES))


def box_foot(
    boxes: ArrayLike,
    cut: ArrayLike | None = None,
    *,
    noise: BoxNoise = DEFAULT_BOX_NOISE,
) -> FootMeasurement:
    """Return the foot point of each box (its bottom centre) with its covariance.

    boxes: (N, 4) or (4,) as (x0, y0, x1, y1) in distorted pixels, x0 < x1 and y0 < y1;
    cut: (N, 4) bool, the sides cut by the image's edge or a mask, columns in BOX_SIDES order
    (bottom, top, left, right) (None: nothing cut); noise: the model of the module docstring.
    """
    try:
        arr = np.asarray(boxes, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"boxes must be numeric, shape (N, 4): {exc}") from None
    b = as_points(arr.reshape(1, -1) if arr.ndim == 1 else arr, 4, "boxes")
    n = b.shape[0]
    if np.any(b[:, 2] <= b[:, 0]) or np.any(b[:, 3] <= b[:, 1]):
        i = int(np.flatnonzero((b[:, 2] <= b[:, 0]) | (b[:, 3] <= b[:, 1]))[0])
        raise InvalidInput(
            f"box {i} is {b[i].tolist()}: a box is (x0, y0, x1, y1) with x0 < x1 and y0 < y1"
        )
    c = np.zeros((n, len(BOX_SIDES)), dtype=bool) if cut is None else np.asarray(cut, dtype=bool)
    if c.shape != (n, len(BOX_SIDES)):
        raise InvalidInput(f"cut must be ({n}, {len(BOX_SIDES)}) booleans, got {c.shape}")
    w = b[:, 2] - b[:, 0]
    h = b[:, 3] - b[:, 1]
    pixel = np.stack([0.5 * (b[:, 0] + b[:, 2]), b[:, 3]], axis=1)
    s_u = np.maximum(noise.k_u * w, noise.floor_px)
    side_cut = c[:, BOX_SIDES.index("left")] | c[:, BOX_SIDES.index("right")]
    s_u = np.where(side_cut, np.maximum(s_u, 0.5 * w), s_u)
    s_v = np.maximum(noise.k_v * h, noise.floor_px)
    cov = np.zeros((n, 2, 2))
    cov[:, 0, 0] = s_u**2
    cov[:, 1, 1] = s_v**2
    measured = ~c[:, BOX_SIDES.index("bottom")]
    return FootMeasurement(pixel=pixel, cov=cov, measured=measured)


def foot_on_axis(
    boxes: ArrayLike,
    foot: FootMeasurement,
    camera: NetworkCamera,
    *,
    radius: float = 0.2,
    radius_sigma: float = 0.03,
) -> FootMeasurement:
    """Return the feet of `foot` (box_foot of `boxes` (N, 4), seen by `camera`) moved to the
    foot of each body's vertical axis, on the floor.

    Two corrections of the bottom centre, both from the camera's geometry:

    * lean: a tilted camera images a vertical body leaning towards the vertical vanishing point
      v_z ~ K R e_z, so the box's horizontal centre is halfway between the images of the feet
      and the head, not above the feet. With the box's bottom and top centres undistorted
      (x_c, v_b), (x_c, v_t) and the axis through v_z and the box's middle (x_c, v_m), the feet
      are at u_f = x_c + (v_b - v_m) s, s = (c x_c - a) / (c v_m - b) for v_z = (a, b, c);
    * near edge: the feet's ray meets the floor at F (core.localization.locate_monocular, with
      the foot's covariance), the body's nearest point; the axis is P = F + r u, u the
      horizontal unit vector from the camera's centre to F, r = `radius` (m).

    P projects back to the pixel reported, with the covariance J (cov_F + radius_sigma^2 u u^T)
    J^T, J = d pixel / d(X, Y) at P. A foot whose ray does not meet the floor in front of the
    camera is no longer `measured`.
    """
    if not (np.isfinite(radius) and radius >= 0 and np.isfinite(radius_sigma)):
        raise InvalidInput("radius and radius_sigma must be finite, radius >= 0")
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    pixel, cov, measured = foot.pixel.copy(), foot.cov.copy(), foot.measured.copy()
    idx = np.flatnonzero(measured)
    if idx.size == 0:
        return FootMeasurement(pixel, cov, measured)
    xc = 0.5 * (b[idx, 0] + b[idx, 2])
    ends = np.stack([np.stack([xc, b[idx, 3]], -1), np.stack([xc, b[idx, 1]], -1)], 1)
    ideal = undistort_points(ends.reshape(-1, 2), camera.K, camera.dist, to_pixels=True)
    ideal = ideal.reshape(-1, 2, 2)
    a_, b_, c_ = camera.K @ camera.R[:, 2]
    x_i = 0.5 * (ideal[:, 0, 0] + ideal[:, 1, 0])
    v_b, v_t = ideal[:, 0, 1], ideal[:, 1, 1]
    v_m = 0.5 * (v_b + v_t)
    den = c_ * v_m - b_
    slope = np.where(np.abs(den) > 1e-9, (c_ * x_i - a_) / np.where(den == 0, 1.0, den), 0.0)
    feet = np.stack([x_i + (v_b - v_m) * slope, v_b], -1)
    m = np.linalg.solve(camera.K, np.c_[feet, np.ones(len(feet))].T).T[:, :2]
    feet_px = distort_to_pixels(camera, m)[0]
    floor = locate_monocular(camera, feet_px, 0.0, pixel_cov=cov[idx])
    ok = floor.status == PointStatus.OK
    good = idx[ok]
    measured[idx[~ok]] = False
    if good.size:
        F = floor.point[ok, :2]
        d = F - camera.center[:2]
        u = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
        P = F + radius * u
        proj = project_plane(camera, P, 0.0, jacobian=True)
        assert proj.jacobian is not None
        cov_floor = floor.point_cov[ok, :2, :2] + radius_sigma**2 * u[:, :, None] * u[:, None, :]
        J = proj.jacobian
        pixel[good] = proj.pixels
        cov[good] = J @ cov_floor @ J.transpose(0, 2, 1)
    return FootMeasurement(pixel, cov, measured)
