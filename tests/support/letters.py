"""Letter-shaped polygons for the image-moment tests and bench: ~60 x 100 px, centred on the
origin, with no symmetry of any kind, and their masks rasterised at 1/16 px vertex precision."""

from __future__ import annotations

import cv2
import numpy as np

LETTER_F = np.array(
    [
        [0, 0],
        [60, 0],
        [60, 14],
        [16, 14],
        [16, 40],
        [48, 40],
        [48, 54],
        [16, 54],
        [16, 100],
        [0, 100],
    ],
    dtype=np.float64,
) - [30.0, 50.0]
LETTER_L = np.array(
    [[0, 0], [18, 0], [18, 80], [55, 80], [55, 100], [0, 100]], dtype=np.float64
) - [25.0, 50.0]


def raster_polygon(poly: np.ndarray, size: int) -> np.ndarray:
    """Return a size x size uint8 mask, 1 inside the polygon (N, 2) pixels (1/16 px vertex
    precision), 0 elsewhere."""
    mask = np.zeros((size, size), np.uint8)
    cv2.fillPoly(mask, [np.round(poly * 16).astype(np.int32)], 1, shift=4)
    return mask
