"""NetworkCamera: pose conventions, projection against OpenCV, visibility."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from localization_scene import IMAGE_SIZE, make_cameras

from core.errors import InvalidInput
from core.localization import NetworkCamera


def test_pose_round_trip_and_center():
    cam = make_cameras(1)[0]
    T = cam.T_world_camera
    again = NetworkCamera.from_pose(cam.K, cam.dist, T, cam.image_size)
    # Pure float64 algebra on unit-norm matrices: round-off only.
    assert np.allclose(again.R, cam.R, atol=1e-15)
    assert np.allclose(again.t, cam.t, atol=1e-14)
    assert np.allclose(T[:3, 3], [0.15, 0.15, 2.8], atol=1e-14)
    assert np.allclose(cam.center, T[:3, 3], atol=1e-14)


def test_looking_at_puts_the_target_on_the_optical_axis_and_keeps_x_horizontal():
    K = np.array([[800.0, 0.0, 640.0], [0.0, 800.0, 400.0], [0.0, 0.0, 1.0]])
    target = np.array([4.0, 3.0, 0.0])
    cam = NetworkCamera.looking_at(K, None, (0.5, 0.5, 2.8), target, IMAGE_SIZE)
    assert np.allclose(cam.project(target[None]), [[640.0, 400.0]], atol=1e-9)
    x_axis_world = cam.R[0]
    assert abs(x_axis_world[2]) < 1e-15
    # y (image down) points down in the world: a camera looking down keeps the image upright.
    assert cam.R[1, 2] < 0


def test_projection_matches_opencv_with_distortion():
    cam = make_cameras(2)[1]
    rng = np.random.default_rng(3)
    X = np.column_stack([rng.uniform(1, 7, 50), rng.uniform(1, 5, 50), rng.uniform(0, 1.5, 50)])
    ref, _ = cv2.projectPoints(X, cam.rvec, cam.t, cam.K, cam.dist)
    # Same model, different code: agreement to round-off of pixel-sized numbers.
    assert np.allclose(cam.project(X), ref[:, 0], atol=1e-9)


def test_in_view_rejects_points_behind_outside_and_folded_back():
    cam = make_cameras(1)[0]
    inside = np.array([[4.0, 3.0, 0.0]])
    behind = np.array([[-3.0, -3.0, 2.8]])
    assert cam.in_view(inside).tolist() == [True]
    assert cam.in_view(behind).tolist() == [False]
    # Below the camera itself: far outside the field of view.
    assert cam.in_view(np.array([[0.2, 0.2, 0.0]])).tolist() == [False]

    # k1 = -0.5 folds ideal radius sqrt(2) onto the principal point: the projection of such a
    # point lands inside the image although the lens cannot see it.
    K = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 200.0], [0.0, 0.0, 1.0]])
    strong = NetworkCamera(K, np.array([-0.5, 0, 0, 0, 0]), np.eye(3), np.zeros(3), (640, 400))
    far = np.array([[1.4, 0.0, 1.0]])
    uv = strong.project(far)[0]
    assert 0 <= uv[0] < 640 and 0 <= uv[1] < 400
    assert strong.in_view(far).tolist() == [False]
    assert strong.in_view(np.array([[0.2, 0.1, 1.0]])).tolist() == [True]


def test_invalid_camera_descriptions_raise():
    K = np.eye(3)
    with pytest.raises(InvalidInput, match="rotation"):
        NetworkCamera(K, np.zeros(5), np.diag([1.0, 1.0, -1.0]), np.zeros(3))
    with pytest.raises(InvalidInput, match="upper triangular"):
        NetworkCamera(np.array([[1.0, 0, 0], [1.0, 1, 0], [0, 0, 1]]), None, np.eye(3), [0, 0, 0])
    with pytest.raises(InvalidInput, match="dist"):
        NetworkCamera(K, np.zeros(6), np.eye(3), np.zeros(3))
    with pytest.raises(InvalidInput, match="vertically"):
        NetworkCamera.looking_at(K, None, (0, 0, 3), (0, 0, 0))
    with pytest.raises(InvalidInput, match="last row"):
        NetworkCamera.from_pose(K, None, np.ones((4, 4)))


def test_plane_projection_and_jacobians_match_the_camera_model():
    # The estimators' lean projection restates core.geometry.camera's model: hold them equal.
    from core.geometry.camera import project_points
    from core.localization._projection import normalized_to_pixel_jacobian, project_plane

    cam = make_cameras(3)[2]
    rng = np.random.default_rng(8)
    xy = np.column_stack([rng.uniform(1, 7, 300), rng.uniform(1, 5, 300)])
    h = 0.3
    X = np.column_stack([xy, np.full(300, h)])
    ref = project_points(X, cam.rvec, cam.t, cam.K, cam.dist, jacobians=True)
    got = project_plane(cam, xy, h, jacobian=True)
    assert ref.d_pose is not None and got.jacobian is not None
    # Same formulas in a different order: agreement to round-off.
    assert np.allclose(got.pixels, ref.points, rtol=0, atol=1e-9)
    assert np.allclose(got.depth, ref.depth, rtol=1e-14, atol=0)
    assert np.allclose(got.jacobian, ref.d_pose[:, :, 3:] @ cam.R[:, :2], rtol=1e-12, atol=1e-9)
    m = rng.uniform(-0.8, 0.8, (300, 2))
    ref_m = project_points(
        np.column_stack([m, np.ones(300)]),
        np.zeros(3),
        np.zeros(3),
        cam.K,
        cam.dist,
        jacobians=True,
    )
    assert ref_m.d_pose is not None
    assert np.allclose(
        normalized_to_pixel_jacobian(cam, m), ref_m.d_pose[:, :, 3:5], rtol=1e-12, atol=1e-9
    )
