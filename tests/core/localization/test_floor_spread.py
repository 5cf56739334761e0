"""The floor spread in pixels: mapped back to the floor through the camera it is sigma^2 I, the
reference being locate_monocular's own covariance propagation (an independent path: J^-1 S J^-T)."""

from __future__ import annotations

import numpy as np

from core.localization import NetworkCamera
from core.localization.floor_spread import floor_spread_cov
from core.localization.ground import locate_monocular


def test_floor_spread_maps_back_to_an_isotropic_floor_covariance() -> None:
    K = [[700.0, 0.0, 640.0], [0.0, 700.0, 360.0], [0.0, 0.0, 1.0]]
    dist = [-0.12, 0.03, 5e-4, -3e-4, -2e-3]
    cam = NetworkCamera.looking_at(K, dist, [0.0, 0.0, 2.8], [3.0, 2.0, 0.0], (1280, 720))
    pts = np.array([[3.0, 2.0, 0.0], [1.5, 2.5, 0.0], [4.0, 0.5, 0.0]])
    px = cam.project(pts)
    sigma = np.array([0.3, 0.1, 0.5])
    S = floor_spread_cov(cam, px, sigma)
    back = locate_monocular(cam, px, 0.0, pixel_cov=S).point_cov[:, :2, :2]
    # First-order propagation both ways: exact up to rounding.
    np.testing.assert_allclose(back, sigma[:, None, None] ** 2 * np.eye(2), rtol=1e-6, atol=1e-12)
    # Foreshortening: the spread is not isotropic in the image.
    ev = np.linalg.eigvalsh(S[0])
    assert ev[1] / ev[0] > 1.5
    # Above the horizon: no floor point, an infinite spread.
    flat = NetworkCamera.looking_at(K, None, [0.0, 0.0, 2.8], [3.0, 2.0, 0.0], (1280, 720))
    horizon_v = flat.project(np.array([[3000.0, 2000.0, 0.0]]))[0, 1]  # -101 px
    assert np.all(np.isinf(floor_spread_cov(flat, [[640.0, horizon_v - 50.0]], 0.3)))


def test_a_pixel_the_lens_cannot_invert_gets_an_infinite_spread_and_spares_the_others():
    # A strong barrel lens (k1 = -0.6) folds back beyond some radius: pixels there have no ray.
    # A held box at such a pixel says nothing of the floor; it must not take the frame's other
    # boxes down with it (the batch's undistortion gives up on all of them together).
    K = np.array([[300.0, 0.0, 320.0], [0.0, 300.0, 240.0], [0.0, 0.0, 1.0]])
    cam = NetworkCamera.looking_at(
        K, np.array([-0.6, 0, 0, 0, 0]), [0, 0, 2.8], [2, 0, 0], (640, 480)
    )
    S = floor_spread_cov(cam, [[320.0, 240.0], [-1000.0, 240.0]], 0.5)
    assert np.all(np.isinf(S[1]))
    alone = floor_spread_cov(cam, [[320.0, 240.0]], 0.5)
    np.testing.assert_allclose(S[0], alone[0])
    assert np.all(np.isfinite(S[0])) and np.linalg.det(S[0]) > 0
