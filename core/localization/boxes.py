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
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_points
from core.errors import InvalidInput

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
