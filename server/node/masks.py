"""Image regions a camera node ignores (a television, a window, a neighbour's door).

A mask is given as polygons of pixels (x, y), each >= 3 vertices; the masked pixels are set to
black before detection, in the background model's frames too, so a moving picture there is
neither a person nor, being colourless, the robot's marker.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput


def polygon_mask(
    size: tuple[int, int], polygons: Sequence[Sequence[Sequence[float]]]
) -> NDArray[np.bool_] | None:
    """Return the (H, W) boolean mask of the pixels inside any of `polygons` ((x, y) pixel
    vertices) for an image of `size` (width, height); None when there are no polygons.

    Raises InvalidInput for a polygon with fewer than 3 vertices or a non-finite vertex."""
    if not polygons:
        return None
    width, height = size
    mask = np.zeros((height, width), dtype=np.uint8)
    for i, polygon in enumerate(polygons):
        pts = np.asarray(polygon, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[0] < 3 or pts.shape[1] != 2:
            raise InvalidInput(f"mask polygon {i} must be >= 3 (x, y) vertices, got {pts.shape}")
        if not np.all(np.isfinite(pts)):
            raise InvalidInput(f"mask polygon {i} has a non-finite vertex")
        cv2.fillPoly(mask, [np.round(pts).astype(np.int32)], 1)
    return mask.astype(bool)


def apply_mask(image: NDArray[np.uint8], mask: NDArray[np.bool_] | None) -> NDArray[np.uint8]:
    """Return `image` with the masked pixels black (a copy; `image` itself when no mask).

    Raises InvalidInput when the mask's shape is not the image's (H, W)."""
    if mask is None:
        return image
    if mask.shape != image.shape[:2]:
        raise InvalidInput(
            f"the mask is {mask.shape[1]}x{mask.shape[0]} px but the image is "
            f"{image.shape[1]}x{image.shape[0]}: give the camera's image size"
        )
    out = image.copy()
    out[mask] = 0
    return out
