"""Polygon areas and centroids (core.geometry.polygon), against OpenCV's and by hand."""

from __future__ import annotations

import cv2
import numpy as np

from core.geometry.polygon import area_centroid, signed_area


def test_centroid_of_an_l_shape():
    # Two rectangles: 6x3 centred (3, 1.5) and 3x2 centred (4.5, 4); area-weighted mean.
    p = np.array([[0, 0], [6, 0], [6, 5], [3, 5], [3, 3], [0, 3]], dtype=float)
    assert signed_area(p) == 24.0
    np.testing.assert_allclose(area_centroid(p), [(18 * 3 + 6 * 4.5) / 24, (18 * 1.5 + 6 * 4) / 24])
    # Clockwise: the same centroid, the area negated.
    assert signed_area(p[::-1]) == -24.0
    np.testing.assert_allclose(area_centroid(p[::-1]), area_centroid(p), rtol=1e-15)


def test_a_batch_of_polygons_matches_opencvs_moments_one_by_one():
    rng = np.random.default_rng(3)
    # Polygons star-shaped about a centre (one vertex per 1/n turn +- 0.4/n: every gap under
    # half a turn, so counter-clockwise), 3-48 vertices, pixel-sized.
    for n in (3, 7, 48):
        angles = (np.arange(n) + rng.uniform(0, 0.4, size=(20, n))) * 2 * np.pi / n
        radii = rng.uniform(5, 200, size=(20, n))
        centre = rng.uniform(-500, 500, size=(20, 1, 2))
        p = centre + radii[..., None] * np.stack([np.cos(angles), np.sin(angles)], axis=-1)
        area, centroid = signed_area(p), area_centroid(p)
        assert area.shape == (20,) and centroid.shape == (20, 2)
        assert np.all(area > 0)  # star-shaped about the centre, counter-clockwise
        for k in range(20):
            m = cv2.moments(p[k].astype(np.float32))
            # OpenCV sums in float32 vertices (~6e-8 relative) with its own rounding: 1e-5
            # relative leaves room for both and still catches any wrong term. Its m00's sign
            # is not the orientation's, so the magnitude is compared (the sign is above).
            np.testing.assert_allclose(area[k], abs(m["m00"]), rtol=1e-5)
            np.testing.assert_allclose(
                centroid[k], [m["m10"] / m["m00"], m["m01"] / m["m00"]], rtol=1e-5, atol=1e-4
            )


def test_a_polygon_without_area_has_its_vertex_mean_for_centroid():
    p = np.array([[0.0, 0.0], [1.0, 1.0], [3.0, 3.0]])  # collinear
    assert signed_area(p) == 0.0
    np.testing.assert_array_equal(area_centroid(p), [4.0 / 3.0, 4.0 / 3.0])
