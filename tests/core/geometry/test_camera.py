"""Camera model: projection and Jacobians against OpenCV and finite differences; undistortion."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from core.errors import InvalidInput
from core.geometry.camera import (
    distort_normalized,
    intrinsics_to_matrix,
    left_jacobian_so3,
    matrix_to_intrinsics,
    project_points,
    undistort_points,
)
from core.geometry.rotations import rotvec_to_matrix

K = np.array([[800.0, 0.0, 320.0], [0.0, 810.0, 240.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.21, 0.09, 0.0012, -0.0021, -0.02])


def scene(m: int = 3, n: int = 12, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    X = np.concatenate([rng.uniform(-0.3, 0.3, (m, n, 2)), rng.uniform(-0.1, 0.1, (m, n, 1))], -1)
    rvec = rng.normal(0.0, 0.5, (m, 3))
    tvec = np.array([0.05, -0.03, 1.2]) + rng.normal(0.0, 0.05, (m, 3))
    return X, rvec, tvec


def test_projection_matches_opencv_with_full_distortion() -> None:
    X, rvec, tvec = scene()
    ours = project_points(X, rvec, tvec, K, DIST).points
    for j in range(len(X)):
        ref, _ = cv2.projectPoints(X[j], rvec[j], tvec[j], K, DIST)
        # Both evaluate the same closed formula in double precision: agreement to 1e-9 px.
        np.testing.assert_allclose(ours[j], ref[:, 0], rtol=0, atol=1e-9)


def test_skew_acts_on_distorted_coordinates() -> None:
    X, rvec, tvec = scene(m=1)
    Ks = K.copy()
    Ks[0, 1] = 0.7
    pts = project_points(X[0], rvec[0], tvec[0], Ks, DIST).points
    Xc = X[0] @ rotvec_to_matrix(rvec[0]).T + tvec[0]
    xd = distort_normalized(Xc[:, :2] / Xc[:, 2:], DIST)
    expected = np.stack([800 * xd[:, 0] + 0.7 * xd[:, 1] + 320, 810 * xd[:, 1] + 240], 1)
    np.testing.assert_allclose(pts, expected, rtol=0, atol=1e-9)


def test_jacobians_match_opencv() -> None:
    X, rvec, tvec = scene()
    pr = project_points(X, rvec, tvec, K, DIST, jacobians=True)
    for j in range(len(X)):
        _, jac = cv2.projectPoints(X[j], rvec[j], tvec[j], K, DIST)
        # OpenCV's columns: rvec (3), tvec (3), fx, fy, cx, cy, k1, k2, p1, p2, k3; rows u, v
        # interleaved. Both are analytic: agreement to rounding (1e-9 relative to the largest).
        ours = np.concatenate(
            [pr.d_pose[j], pr.d_intrinsics[j][..., :4], pr.d_distortion[j]], -1
        ).reshape(-1, 15)
        scale = np.abs(jac).max(axis=0)
        np.testing.assert_allclose(ours / scale, jac / scale, rtol=0, atol=1e-9)


def test_jacobians_match_finite_differences_including_skew() -> None:
    X, rvec, tvec = scene(m=2)
    intr = np.array([800.0, 810.0, 320.0, 240.0, 0.9])
    pr = project_points(X, rvec, tvec, intrinsics_to_matrix(intr), DIST, jacobians=True)

    def num(f, x: np.ndarray, h: float) -> np.ndarray:
        cols = []
        for k in range(len(x)):
            dx = np.zeros_like(x)
            dx[k] = h
            cols.append((f(x + dx) - f(x - dx)) / (2 * h))
        return np.stack(cols, -1)

    # Central differences: truncation O(h^2) and rounding O(eps u / h); with these steps both
    # stay below 1e-6 of each column's magnitude.
    d_int = num(
        lambda p: project_points(X, rvec, tvec, intrinsics_to_matrix(p), DIST).points, intr, 1e-4
    )
    d_dist = num(
        lambda d: project_points(X, rvec, tvec, intrinsics_to_matrix(intr), d).points, DIST, 1e-7
    )
    for got, ref in ((pr.d_intrinsics, d_int), (pr.d_distortion, d_dist)):
        scale = np.abs(ref).max(axis=(0, 1, 2))
        np.testing.assert_allclose(got / scale, ref / scale, rtol=0, atol=1e-6)
    for j in range(2):
        d_pose = num(
            lambda q, j=j: (
                project_points(X[j], q[:3], q[3:], intrinsics_to_matrix(intr), DIST).points
            ),
            np.concatenate([rvec[j], tvec[j]]),
            1e-7,
        )
        scale = np.abs(d_pose).max(axis=(0, 1))
        np.testing.assert_allclose(pr.d_pose[j] / scale, d_pose / scale, rtol=0, atol=1e-6)


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-4, 1.0, np.pi - 1e-3])
def test_left_jacobian_is_the_derivative_of_rotation(angle: float) -> None:
    axis = np.array([0.3, -0.5, 0.81])
    v = axis / np.linalg.norm(axis) * angle
    Jl = left_jacobian_so3(v)
    h = 1e-7
    for k in range(3):
        dv = np.zeros(3)
        dv[k] = h
        dR = (rotvec_to_matrix(v + dv) - rotvec_to_matrix(v - dv)) / (2 * h)
        omega = dR @ rotvec_to_matrix(v).T  # = [J_l e_k]x
        got = np.array([omega[2, 1], omega[0, 2], omega[1, 0]])
        # Central difference of R: error ~ h^2 + eps / h ~ 1e-9.
        np.testing.assert_allclose(got, Jl[:, k], rtol=0, atol=1e-8)


def test_undistort_inverts_distortion_to_machine_precision() -> None:
    rng = np.random.default_rng(3)
    xy = rng.uniform(-0.5, 0.5, (500, 2))
    Ks = K.copy()
    Ks[0, 1] = 0.4
    xd = distort_normalized(xy, DIST)
    pix = np.stack([800 * xd[:, 0] + 0.4 * xd[:, 1] + 320, 810 * xd[:, 1] + 240], 1)
    # Newton converges quadratically; the residual is rounding, ~1e-16 in normalised units.
    np.testing.assert_allclose(undistort_points(pix, Ks, DIST), xy, rtol=0, atol=1e-13)
    ideal = undistort_points(pix, Ks, DIST, to_pixels=True)
    expected = xy @ Ks[:2, :2].T + Ks[:2, 2]
    np.testing.assert_allclose(ideal, expected, rtol=0, atol=1e-9)


def test_undistort_agrees_with_opencv() -> None:
    rng = np.random.default_rng(4)
    pix = rng.uniform([0, 0], [640, 480], (200, 2))
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    ref = cv2.undistortPoints(pix[:, None], K, DIST, criteria=crit)[:, 0]
    # OpenCV iterates a fixed point to its criteria; 1e-9 in normalised coordinates is 1e-6 px.
    np.testing.assert_allclose(undistort_points(pix, K, DIST), ref, rtol=0, atol=1e-9)


def test_batched_projection_equals_per_view() -> None:
    X, rvec, tvec = scene(m=4, n=5)
    batch = project_points(X, rvec, tvec, K, DIST, jacobians=True)
    for j in range(4):
        one = project_points(X[j], rvec[j], tvec[j], K, DIST, jacobians=True)
        np.testing.assert_array_equal(batch.points[j], one.points)
        np.testing.assert_allclose(batch.d_pose[j], one.d_pose, rtol=1e-14, atol=1e-12)


def test_intrinsics_round_trip_and_bad_input() -> None:
    p = np.array([800.0, 810.0, 320.0, 240.0, 0.5])
    np.testing.assert_array_equal(matrix_to_intrinsics(intrinsics_to_matrix(p)), p)
    with pytest.raises(InvalidInput):
        project_points(np.zeros((4, 2)), np.zeros(3), np.ones(3), K)
    with pytest.raises(InvalidInput):
        project_points(np.zeros((4, 3)), np.zeros(3), np.ones(3), K, np.zeros(6))
    with pytest.raises(InvalidInput):
        undistort_points(np.zeros((4, 3)), K, DIST)


# OpenCV's longer models. A wide-angle ceiling camera calibrated with the rational model: the
# numerator and denominator of rad nearly cancel (values of that size are what
# calibrateCamera(CALIB_RATIONAL_MODEL) returns for such lenses); prism and tilt small but not
# zero, so that every term is exercised.
RATIONAL = np.array([2.3, 0.9, 0.0005, -0.0003, 0.02, 2.7, 1.6, 0.15])
PRISM = np.concatenate([RATIONAL, [0.003, -0.001, 0.002, 0.0005]])
TILTED = np.concatenate([PRISM, [0.02, -0.03]])
K_WIDE = np.array([[640.0, 0.0, 642.0], [0.0, 638.0, 358.0], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize("dist", [RATIONAL, PRISM, TILTED], ids=["8", "12", "14"])
def test_long_distortion_projection_and_jacobian_match_opencv(dist: np.ndarray) -> None:
    X, rvec, tvec = scene(m=3, n=20, seed=4)
    pr = project_points(X, rvec, tvec, K_WIDE, dist, jacobians=True)
    assert pr.d_distortion is not None and pr.d_distortion.shape[-1] == 14
    for j in range(len(X)):
        ref, jac = cv2.projectPoints(X[j], rvec[j], tvec[j], K_WIDE, dist)
        # The same closed formula in double precision on both sides: 1e-9 px (the bound;
        # measured ~1e-12).
        np.testing.assert_allclose(pr.points[j], ref[:, 0], rtol=0, atol=1e-9)
        assert pr.d_pose is not None and pr.d_intrinsics is not None
        # cv2's columns: rvec, tvec, fx, fy, cx, cy, then the coefficients given.
        ours = np.concatenate(
            [pr.d_pose[j], pr.d_intrinsics[j][..., :4], pr.d_distortion[j][..., : dist.size]], -1
        )
        np.testing.assert_allclose(ours, jac.reshape(-1, 2, jac.shape[-1]), rtol=0, atol=1e-9)


@pytest.mark.parametrize("dist", [RATIONAL, PRISM, TILTED], ids=["8", "12", "14"])
def test_long_distortion_undistortion_matches_opencv_iterated(dist: np.ndarray) -> None:
    # A grid over a 1280 x 720 image, corners included, where the distortion is strongest.
    u, v = np.meshgrid(np.linspace(0, 1279, 17), np.linspace(0, 719, 9))
    pixels = np.column_stack([u.ravel(), v.ravel()])
    ours = undistort_points(pixels, K_WIDE, dist)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-16)
    ref = cv2.undistortPoints(pixels[:, None], K_WIDE, dist, None, None, None, criteria)[:, 0]
    # Both converge to the exact inverse: 1e-9 px once scaled by the focal length.
    np.testing.assert_allclose(ours * K_WIDE[0, 0], ref * K_WIDE[0, 0], rtol=0, atol=1e-9)
    # And ours is the inverse: distorting it again gives the pixels back.
    back = distort_normalized(ours, dist) * [K_WIDE[0, 0], K_WIDE[1, 1]] + K_WIDE[:2, 2]
    np.testing.assert_allclose(back, pixels, rtol=0, atol=1e-9)


@pytest.mark.parametrize("dist", [RATIONAL, TILTED], ids=["8", "14"])
def test_network_cameras_take_long_distortion(dist: np.ndarray) -> None:
    from core.localization._projection import distort_to_pixels
    from core.localization.cameras import NetworkCamera

    T = np.array([[1.0, 0, 0, 1.0], [0, -1.0, 0, 2.0], [0, 0, -1.0, 2.6], [0, 0, 0, 1.0]])
    cam = NetworkCamera.from_pose(K_WIDE, dist, T, (1280, 720))
    X = np.array([[1.3, 2.2, 0.0], [0.1, 1.1, 0.9], [2.5, 3.0, 0.0]])
    rvec, _ = cv2.Rodrigues(cam.R)
    ref, _ = cv2.projectPoints(X, rvec, cam.t, K_WIDE, dist)
    np.testing.assert_allclose(cam.project(X), ref[:, 0], rtol=0, atol=1e-9)
    # The estimators' 2 x 2 Jacobian d pixel / d m against central differences (h = 1e-6 in
    # normalised units: truncation ~h^2 * |third derivative| ~ 1e-9 of a ~1e3 px Jacobian).
    m = np.array([[0.31, -0.42], [-0.6, 0.25], [0.05, 0.02]])
    _, B = distort_to_pixels(cam, m, jacobian=True)
    assert B is not None
    h = 1e-6
    for k in range(2):
        step = np.zeros(2)
        step[k] = h
        plus, _ = distort_to_pixels(cam, m + step)
        minus, _ = distort_to_pixels(cam, m - step)
        np.testing.assert_allclose(B[:, :, k], (plus - minus) / (2 * h), rtol=1e-6, atol=1e-5)
    with pytest.raises(InvalidInput):
        NetworkCamera.from_pose(K_WIDE, np.zeros(9), T, (1280, 720))
