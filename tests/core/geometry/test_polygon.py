"""The shoelace area of core.geometry.polygon against OpenCV's contour area."""

from __future__ import annotations

import cv2
import numpy as np

from core.geometry.polygon import signed_area


def test_signed_area_is_positive_counter_clockwise_and_matches_opencv() -> None:
    # A unit square counter-clockwise (x right, y up) has area +1, clockwise -1.
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    assert signed_area(square) == 1.0
    assert signed_area(square[::-1]) == -1.0
    # An L-shaped room of 3 x 2 minus 1 x 1: 5 square metres.
    room = np.array([[0, 0], [3, 0], [3, 2], [1, 2], [1, 1], [0, 1]], float)
    assert signed_area(room) == 5.0
    # Star-shaped polygons about the origin with integer vertices (exact in OpenCV's float32 and
    # in the products, so both areas are exact: equal to the last bit), one vertex in each of n
    # equal sectors, by increasing angle (consecutive ones less than pi apart: the origin inside,
    # the polygon counter-clockwise): the same magnitude as cv2.contourArea, positive.
    rng = np.random.default_rng(0)
    for n in (4, 7, 40):
        for _ in range(20):
            angles = (np.arange(n) + rng.uniform(0, 1, n)) * 2 * np.pi / n
            radii = rng.uniform(10, 500, n)
            p = np.rint(np.stack([radii * np.cos(angles), radii * np.sin(angles)], 1))
            reference = float(cv2.contourArea(p.astype(np.float32)))
            assert signed_area(p) == reference
            assert signed_area(p[::-1]) == -reference
