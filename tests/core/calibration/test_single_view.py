"""Single-view calibration with a known principal point: exact, vs OpenCV, degenerate views."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from core.calibration import calibrate_single_view, focal_from_homography
from core.errors import DegenerateConfiguration, InvalidInput, NotEnoughPoints
from core.geometry.camera import project_points
from core.geometry.rotations import rotvec_to_matrix
from core.homography import dlt_homography

PP = (330.0, 250.0)
RVEC = np.array([0.45, -0.35, 0.1])
TVEC = np.array([-0.1, -0.05, 0.6])


def board() -> np.ndarray:
    gx, gy = np.meshgrid(np.arange(9), np.arange(6))
    return np.stack([gx.ravel() * 0.03, gy.ravel() * 0.03, np.zeros(gx.size)], 1)


def camera(fx: float, fy: float) -> np.ndarray:
    return np.array([[fx, 0.0, PP[0]], [0.0, fy, PP[1]], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize(("unit_aspect", "fy"), [(True, 900.0), (False, 870.0)])
def test_noise_free_is_exact(unit_aspect: bool, fy: float) -> None:
    X = board()
    K = camera(900.0, fy)
    uv = project_points(X, RVEC, TVEC, K).points
    # Closed form on the exact homography: rounding only.
    f = focal_from_homography(dlt_homography(X[:, :2], uv), PP, unit_aspect=unit_aspect)
    np.testing.assert_allclose(f, (900.0, fy), rtol=1e-9)
    c = calibrate_single_view(X, uv, PP, unit_aspect=unit_aspect)
    np.testing.assert_allclose(c.K, K, rtol=0, atol=1e-9 * 900)
    np.testing.assert_allclose(c.pose.R, rotvec_to_matrix(RVEC), rtol=0, atol=1e-9)
    np.testing.assert_allclose(c.pose.t, TVEC, rtol=0, atol=1e-9)
    assert c.rms < 1e-9
    assert c.unit_aspect is unit_aspect


def test_noise_free_with_known_distortion_is_exact() -> None:
    X = board()
    K = camera(900.0, 900.0)
    dist = np.array([-0.2, 0.08, 0.001, -0.0015, 0.0])
    uv = project_points(X, RVEC, TVEC, K, dist).points
    c = calibrate_single_view(X, uv, PP, dist=dist)
    np.testing.assert_allclose(c.K, K, rtol=0, atol=1e-9 * 900)
    np.testing.assert_allclose(c.pose.t, TVEC, rtol=0, atol=1e-9)


def test_unit_aspect_matches_opencv_single_view_optimum() -> None:
    # cv2.calibrateCamera on one view with the principal point, aspect ratio, skew and all
    # distortion held fixed minimises the same reprojection error over (f, pose).
    rng = np.random.default_rng(5)
    X = board().astype(np.float32).astype(np.float64)  # OpenCV takes float32; same data for both
    K = camera(900.0, 900.0)
    uv = project_points(X, RVEC, TVEC, K).points + rng.normal(0.0, 0.5, (len(X), 2))
    uv32 = uv.astype(np.float32)
    c = calibrate_single_view(X, uv32.astype(np.float64), PP)
    flags = (
        cv2.CALIB_USE_INTRINSIC_GUESS
        | cv2.CALIB_FIX_PRINCIPAL_POINT
        | cv2.CALIB_FIX_ASPECT_RATIO
        | cv2.CALIB_ZERO_TANGENT_DIST
        | cv2.CALIB_FIX_K1
        | cv2.CALIB_FIX_K2
        | cv2.CALIB_FIX_K3
    )
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, np.finfo(float).eps)
    rms, Kcv, *_ = cv2.calibrateCamera(
        [X.astype(np.float32)],
        [uv32],
        (660, 500),
        camera(850.0, 850.0),
        np.zeros(5),
        flags=flags,
        criteria=crit,
    )
    # The same minimum: RMS to 1e-8 px; f to 1e-4 of its standard deviation (~11 px here), the
    # room left by the two optimisers' stopping tolerances (measured 3e-6 of it).
    assert abs(c.rms - rms) < 1e-8
    assert abs(c.K[0, 0] - Kcv[0, 0]) < 1e-4 * c.focal_std[0]
    # The estimate is near the truth: within 4 reported standard deviations.
    assert abs(c.K[0, 0] - 900.0) < 4 * c.focal_std[0]
    assert abs(c.initial_K[0, 0] - 900.0) < 0.05 * 900


def test_fronto_parallel_view_raises() -> None:
    X = board()
    uv = project_points(X, np.array([0.0, 0.0, 0.3]), TVEC, camera(900.0, 900.0)).points
    for unit_aspect in (True, False):
        with pytest.raises(DegenerateConfiguration, match="fronto-parallel"):
            calibrate_single_view(X, uv, PP, unit_aspect=unit_aspect)
    with pytest.raises(DegenerateConfiguration, match="fronto-parallel"):
        focal_from_homography(dlt_homography(X[:, :2], uv), PP)


def test_tilt_about_one_axis_fixes_f_but_not_fx_and_fy() -> None:
    X = board()
    K = camera(900.0, 900.0)
    uv = project_points(X, np.array([0.4, 0.0, 0.0]), TVEC, K).points
    with pytest.raises(DegenerateConfiguration, match="one image axis"):
        calibrate_single_view(X, uv, PP, unit_aspect=False)
    c = calibrate_single_view(X, uv, PP, unit_aspect=True)
    np.testing.assert_allclose(c.K, K, rtol=0, atol=1e-9 * 900)


def test_invalid_input_raises() -> None:
    X = board()
    uv = project_points(X, RVEC, TVEC, camera(900.0, 900.0)).points
    with pytest.raises(NotEnoughPoints):
        calibrate_single_view(X[:3], uv[:3], PP)
    with pytest.raises(InvalidInput):
        calibrate_single_view(X, uv[:-1], PP)
    with pytest.raises(InvalidInput):
        calibrate_single_view(X, uv, (np.nan, 2.0))
    bad = uv.copy()
    bad[0, 0] = np.inf
    with pytest.raises(InvalidInput):
        calibrate_single_view(X, bad, PP)
