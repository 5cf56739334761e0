"""The image of the network calibration's disc marker: its centre's offset from the projected
centre and its area, against the renderer's ellipse and counts of the pixels it covers."""

from __future__ import annotations

import numpy as np

from core.calibration.network._marker_image import disc_centre_offset, disc_image_area
from core.geometry.rotations import matrix_to_rotvec
from tests.support.camera_network import DIST, H, K, network


def test_disc_centre_offset_without_distortion_is_the_renderers_ellipse_centre() -> None:
    # Independent reference: core.sim.render's conic centre of the disc's image (H & Z eq.
    # 2.13), exact without distortion. The inscribed 48-gon's centroid differs by O(n^-2) of
    # the perspective offset: measured 8e-4 px, bound 3e-3 px.
    from core.sim.render import CameraModel, _disc_image_centre

    cam = network()[1]
    none = np.zeros(5)
    model = CameraModel("b", 640, 480, K, none, cam.R.T, cam.center, 15.0)
    X = np.array([[1.0, 1.0, H], [3.5, 2.5, H], [0.5, 3.0, H]])
    off = disc_centre_offset(X, matrix_to_rotvec(cam.R), cam.t, K, none, 0.08)
    want = np.array([_disc_image_centre(model, x, 0.08) for x in X]) - model.project(X)
    np.testing.assert_allclose(off, want, atol=3e-3)
    assert np.all(np.linalg.norm(off, axis=1) > 0.02)  # the effect is there to model


def test_disc_centre_offset_is_the_centroid_of_the_pixels_the_disc_covers() -> None:
    # Independent reference, as for the area below: the image plane sampled at 1/8 px, each
    # sample undistorted by OpenCV, its ray met with the disc's plane, and the centroid taken
    # of those within the radius (what a detector's soft centroid measures). With k1 = -0.28
    # that centroid is up to a quarter of a pixel from the distorted ellipse centre the model
    # used to predict (the renderer's truth) for an 8 cm disc near the image's edge, a
    # magnification of the focal length to the model: it must follow the pixels.
    import cv2

    from core.sim.render import CameraModel, _disc_image_centre

    cam = network()[1]
    model = CameraModel("b", 640, 480, K, DIST, cam.R.T, cam.center, 15.0)
    rv, r = matrix_to_rotvec(cam.R), 0.08
    # On the axis, off it, and near the image's lower edge, close to the camera.
    X = np.array([[2.0, 1.8, H], [3.6, 0.6, H], [3.8, 3.3, H]])
    off = disc_centre_offset(X, rv, cam.t, K, DIST, r)
    gaps = []
    for x, o in zip(X, off, strict=True):
        c = cam.project(x[None])[0]
        half = 3 * np.sqrt(disc_image_area(x[None], rv, cam.t, K, DIST, r)[0] / np.pi)
        g = np.arange(-half, half, 0.125) + 0.0625
        u, v = np.meshgrid(c[0] + g, c[1] + g)
        uv = np.stack([u.ravel(), v.ravel()], 1)
        n = cv2.undistortPoints(uv.reshape(-1, 1, 2), K, DIST).reshape(-1, 2)
        rays = np.column_stack([n, np.ones(len(n))]) @ cam.R  # world directions
        lam = (H - cam.center[2]) / rays[:, 2]
        hit = cam.center + lam[:, None] * rays
        inside = np.sum((hit[:, :2] - x[:2]) ** 2, axis=1) <= r * r
        centroid = uv[inside].mean(axis=0)
        # Sampling 1/64 px^2 cells over a few hundred px^2: the centroid to ~0.005 px.
        np.testing.assert_allclose(c + o, centroid, atol=0.01)
        gaps.append(np.linalg.norm(centroid - _disc_image_centre(model, x, r)))
    # Measured 0.004, 0.07 and 0.23 px: the distortion's share is there to model.
    assert max(gaps) > 0.15, gaps


def test_disc_image_area_matches_a_count_of_the_pixels_it_covers() -> None:
    # Independent reference: the image plane sampled at 1/8 px, each sample undistorted by
    # OpenCV (cv2.undistortPoints), its ray met with the disc's plane and counted when it
    # falls within the radius. Sampling 1/64 px^2 cells over a ~700 px^2 image: < 0.5 %.
    import cv2

    cam = network()[1]
    rv, r = matrix_to_rotvec(cam.R), 0.08
    X = np.array([[2.0, 1.8, H], [0.8, 0.9, H]])  # near the image centre, and far off it
    got = disc_image_area(X, rv, cam.t, K, DIST, r)
    for x, area in zip(X, got, strict=True):
        c = cam.project(x[None])[0]
        half = 3 * np.sqrt(area / np.pi)
        g = np.arange(-half, half, 0.125) + 0.0625
        u, v = np.meshgrid(c[0] + g, c[1] + g)
        uv = np.stack([u.ravel(), v.ravel()], 1).reshape(-1, 1, 2)
        n = cv2.undistortPoints(uv, K, DIST).reshape(-1, 2)
        rays = np.column_stack([n, np.ones(len(n))]) @ cam.R  # world directions
        lam = (H - cam.center[2]) / rays[:, 2]
        hit = cam.center + lam[:, None] * rays
        inside = np.sum((hit[:, :2] - x[:2]) ** 2, axis=1) <= r * r
        np.testing.assert_allclose(area, inside.sum() / 64.0, rtol=0.005)
    assert got[1] < 0.9 * got[0]  # oblique and far: smaller
