"""Plane pose with known intrinsics: exact, vs cv2.solvePnP (IPPE, then LM), covariance by Monte
Carlo, degenerate input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from core.calibration import estimate_plane_pose, pose_from_homography
from core.errors import DegenerateConfiguration, InvalidInput, NotEnoughPoints
from core.geometry.camera import project_points
from core.geometry.rotations import matrix_to_rotvec, rotvec_to_matrix
from core.homography import dlt_homography

K = np.array([[900.0, 0.0, 330.0], [0.0, 880.0, 250.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.25, 0.1, 0.001, -0.0008, -0.02])
RVEC = np.array([0.4, -0.3, 0.1])
TVEC = np.array([-0.1, -0.05, 0.6])


def board() -> np.ndarray:
    gx, gy = np.meshgrid(np.arange(9), np.arange(6))
    return np.stack([gx.ravel() * 0.03, gy.ravel() * 0.03, np.zeros(gx.size)], 1)


def test_pose_from_exact_homography_is_exact_and_batched() -> None:
    X = board()
    rvecs = np.array([RVEC, [-0.2, 0.5, 1.0], [0.05, 0.02, -2.5]])
    tvecs = np.array([TVEC, [0.05, 0.0, 1.2], [0.0, 0.1, 0.4]])
    images = [project_points(X, r, t, K).points for r, t in zip(rvecs, tvecs, strict=True)]
    Hs = np.stack([dlt_homography(X[:, :2], uv) for uv in images])
    pose = pose_from_homography(Hs, K)
    # Exact homographies: Zhang eq. (3)-(4) recover R, t up to rounding.
    np.testing.assert_allclose(pose.R, rotvec_to_matrix(rvecs), rtol=0, atol=1e-9)
    np.testing.assert_allclose(pose.t, tvecs, rtol=0, atol=1e-9)
    # H is defined up to scale, including its sign: -H gives the same pose (plane in front).
    flipped = pose_from_homography(-Hs[0], K, X[:, :2])
    np.testing.assert_allclose(flipped.t, tvecs[0], rtol=0, atol=1e-9)


@pytest.mark.parametrize("dist", [None, DIST])
def test_noise_free_pose_is_exact(dist: np.ndarray | None) -> None:
    X = board()
    uv = project_points(X, RVEC, TVEC, K, dist).points
    e = estimate_plane_pose(X, uv, K, dist)
    np.testing.assert_allclose(e.R, rotvec_to_matrix(RVEC), rtol=0, atol=1e-9)
    np.testing.assert_allclose(e.rvec, RVEC, rtol=0, atol=1e-9)
    np.testing.assert_allclose(e.t, TVEC, rtol=0, atol=1e-9)
    assert e.rms < 1e-9
    assert e.covariance.shape == (6, 6)


def test_matches_opencv_ippe_and_its_lm_refinement() -> None:
    rng = np.random.default_rng(8)
    X = board()
    uv = project_points(X, RVEC, TVEC, K, DIST).points + rng.normal(0.0, 0.5, (len(X), 2))
    e = estimate_plane_pose(X, uv, K, DIST)
    ok, rv, tv = cv2.solvePnP(X, uv, K, DIST, flags=cv2.SOLVEPNP_IPPE)
    assert ok
    # IPPE is a closed form, not the reprojection optimum: within a few standard deviations.
    sd = np.sqrt(np.diag(e.covariance))
    diff = np.concatenate([e.rvec - rv.ravel(), e.t - tv.ravel()])
    assert np.all(np.abs(diff) < 4 * sd)
    # OpenCV's LM from IPPE reaches the same minimum; ours is at least as good.
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, np.finfo(float).eps)
    rv2, tv2 = cv2.solvePnPRefineLM(X, uv, K, DIST, rv.copy(), tv.copy(), criteria=crit)
    # Stopping tolerances leave ~1e-6 of a standard deviation; 1e-3 of one is a tight bound.
    diff = np.concatenate([e.rvec - rv2.ravel(), e.t - tv2.ravel()])
    assert np.all(np.abs(diff) < 1e-3 * sd)
    proj = cv2.projectPoints(X, rv2, tv2, K, DIST)[0][:, 0]
    rms_cv = np.sqrt(np.mean(np.sum((proj - uv) ** 2, 1)))
    assert e.rms <= rms_cv + 1e-12
    assert e.iterations > 0


def test_covariance_matches_monte_carlo_scatter() -> None:
    rng = np.random.default_rng(9)
    X = board()
    clean = project_points(X, RVEC, TVEC, K).points
    est, cov = [], []
    for _ in range(300):
        e = estimate_plane_pose(X, clean + rng.normal(0.0, 0.5, clean.shape), K, sigma=0.5)
        est.append(np.concatenate([e.rvec, e.t]))
        cov.append(e.covariance)
    scatter = np.std(est, axis=0, ddof=1)
    predicted = np.sqrt(np.diag(np.mean(cov, axis=0)))
    # Sample std of 300 trials: 1/sqrt(2 * 299) = 4.1 % relative error; 14 % is ~3.4 of those.
    np.testing.assert_allclose(predicted / scatter, np.ones(6), rtol=0, atol=0.14)
    # With sigma estimated from the residuals, the same to within its own scatter.
    e = estimate_plane_pose(X, clean + rng.normal(0.0, 0.5, clean.shape), K)
    ratio = np.sqrt(np.diag(e.covariance)) / predicted
    assert np.all(np.abs(ratio - 1) < 0.3)


def test_degenerate_and_invalid_input_raise() -> None:
    X = board()
    uv = project_points(X, RVEC, TVEC, K).points
    line = np.stack([np.arange(6) * 0.03, np.zeros(6)], 1)
    line_uv = project_points(np.c_[line, np.zeros(6)], RVEC, TVEC, K).points
    with pytest.raises(DegenerateConfiguration):
        estimate_plane_pose(line, line_uv, K)
    with pytest.raises(NotEnoughPoints):
        estimate_plane_pose(X[:3], uv[:3], K)
    bad = uv.copy()
    bad[2, 1] = np.nan
    with pytest.raises(InvalidInput):
        estimate_plane_pose(X, bad, K)
    with pytest.raises(InvalidInput):
        estimate_plane_pose(X, uv, K[:2])
    with pytest.raises(InvalidInput):
        estimate_plane_pose(X, uv[:-1], K)
    with pytest.raises(InvalidInput, match="Z = 0"):
        estimate_plane_pose(X + np.array([0.0, 0.0, 0.1]), uv, K)


def test_rotation_is_orthonormal_and_plane_in_front() -> None:
    rng = np.random.default_rng(10)
    X = board()
    uv = project_points(X, RVEC, TVEC, K).points + rng.normal(0.0, 1.0, (len(X), 2))
    e = estimate_plane_pose(X, uv, K, refine=False)
    assert e.iterations == 0
    np.testing.assert_allclose(e.R @ e.R.T, np.eye(3), rtol=0, atol=1e-12)
    assert np.linalg.det(e.R) > 0
    depth = (X @ e.R.T + e.t)[:, 2]
    assert np.all(depth > 0)
    assert np.allclose(matrix_to_rotvec(e.R), e.rvec)
