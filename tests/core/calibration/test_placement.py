"""Placing a camera from floor points: against OpenCV's solvePnP on the same points, the
covariance against Monte Carlo scatter, degenerate input, and the real PETS 2009 camera."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from core.calibration.placement import CameraPlacement, place_camera
from core.errors import DegenerateConfiguration, NotEnoughPoints

SIZE = (640, 480)
K_TRUE = np.array([[600.0, 0.0, 319.5], [0.0, 600.0, 239.5], [0.0, 0.0, 1.0]])


def _ceiling_camera() -> tuple[np.ndarray, np.ndarray]:
    """Return (R, t) world-to-camera of a camera 2.6 m up in a corner, looking down at the room."""
    centre = np.array([0.2, 0.3, 2.6])
    forward = np.array([2.5, 1.8, 0.0]) - centre
    z = forward / np.linalg.norm(forward)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ centre


def _floor_points(rng: np.random.Generator, n: int, R, t, K=K_TRUE, dist=None):
    """Return n floor points (n, 3) seen inside the image, and their exact pixels (n, 2)."""
    pts, pix = [], []
    while len(pts) < n:
        X = np.array([rng.uniform(0.5, 5.0), rng.uniform(0.5, 4.0), 0.0])
        p, _ = cv2.projectPoints(X[None], cv2.Rodrigues(R)[0], t, K, dist)
        u, v = p[0, 0]
        if 20 < u < SIZE[0] - 20 and 20 < v < SIZE[1] - 20 and (R @ X + t)[2] > 0:
            pts.append(X)
            pix.append((u, v))
    return np.array(pts), np.array(pix)


def _centre(placement: CameraPlacement) -> np.ndarray:
    return placement.T_world_camera[:3, 3]


def _pnp_centre(X, uv, K, dist=None) -> np.ndarray:
    ok, rvec, tvec = cv2.solvePnP(X, uv, K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
    assert ok
    R = cv2.Rodrigues(rvec)[0]
    return -R.T @ tvec[:, 0]


def test_known_intrinsics_match_solvepnp_on_inliers_and_find_the_wrong_click():
    R, t = _ceiling_camera()
    centre = -R.T @ t
    rng = np.random.default_rng(7)
    ours, pnp_inliers, pnp_all, found = [], [], [], 0
    for _ in range(20):
        X, uv = _floor_points(rng, 8, R, t)
        uv = uv + rng.normal(0.0, 0.7, uv.shape)  # careful clicks: ~0.7 px
        bad = int(rng.integers(8))
        clicked = uv.copy()
        clicked[bad] += rng.choice([-1.0, 1.0], 2) * 25.0  # the neighbouring tile's corner
        fit = place_camera(X, clicked, SIZE, K_TRUE)
        found += fit.rejected.tolist() == [bad]
        keep = np.arange(8) != bad
        ours.append(np.linalg.norm(_centre(fit) - centre))
        pnp_inliers.append(np.linalg.norm(_pnp_centre(X[keep], uv[keep], K_TRUE) - centre))
        pnp_all.append(np.linalg.norm(_pnp_centre(X, clicked, K_TRUE) - centre))
    ours_a, inl_a, all_a = np.array(ours), np.array(pnp_inliers), np.array(pnp_all)
    # Both minimise the same reprojection error on the same 7 inliers: the same optimum to
    # LM's tolerance, so equal to 0.1 mm on a camera whose position is good to ~1 cm.
    assert found == 20
    assert np.max(np.abs(ours_a - inl_a)) < 1e-4
    # solvePnP on all 8 points is pulled off by the wrong click: several times further away.
    assert np.median(all_a) > 3.0 * np.median(ours_a)
    print(
        f"camera position error, median of 20: ours {np.median(ours_a) * 100:.2f} cm, "
        f"solvePnP inliers {np.median(inl_a) * 100:.2f} cm, solvePnP all "
        f"{np.median(all_a) * 100:.2f} cm"
    )


def test_unknown_focal_length_and_standard_deviations_agree_with_the_scatter():
    R, t = _ceiling_camera()
    centre = -R.T @ t
    rng = np.random.default_rng(3)
    # 12 points: with 7 parameters, 8 points leave the least-median fit free to explain a
    # few 1 px clicks as wrong pairs; a placement is made with a dozen points or more.
    X, uv0 = _floor_points(rng, 12, R, t)
    sigma = 1.0
    f, c, std_f, std_c = [], [], [], []
    for _ in range(40):
        fit = place_camera(X, uv0 + rng.normal(0.0, sigma, uv0.shape), SIZE)
        assert fit.f_estimated and fit.std_f_px is not None
        f.append(fit.K[0, 0])
        c.append(_centre(fit))
        std_f.append(fit.std_f_px)
        std_c.append(fit.std_position_m)
    f_a, c_a = np.array(f), np.array(c)
    # Unbiased to within 3 standard errors of the mean of 40.
    assert abs(f_a.mean() - 600.0) < 3 * f_a.std() / np.sqrt(40) + 0.5
    assert np.all(np.abs(c_a.mean(0) - centre) < 3 * c_a.std(0) / np.sqrt(40) + 1e-3)
    # The reported standard deviations against the scatter of 40 trials: the sample std of 40
    # is within +-23 % of the truth at 2 sigma (chi-square, 39 dof), and each reported std is
    # itself a 17-dof estimate whose mean over 40 trials is within a few %: +-33 % is ~3 sigma.
    ratio_f = f_a.std(ddof=1) / np.mean(std_f)
    ratio_c = c_a.std(0, ddof=1) / np.mean(std_c, axis=0)
    assert 0.75 < ratio_f < 1.33, ratio_f
    assert np.all((ratio_c > 0.75) & (ratio_c < 1.33)), ratio_c


def test_distorted_camera_with_known_intrinsics():
    R, t = _ceiling_camera()
    dist = np.array([-0.25, 0.08, 0.001, -0.0005, 0.0])
    rng = np.random.default_rng(11)
    X, uv = _floor_points(rng, 10, R, t, K_TRUE, dist)
    uv = uv + rng.normal(0.0, 0.3, uv.shape)
    fit = place_camera(X, uv, SIZE, K_TRUE, dist)
    pnp = _pnp_centre(X, uv, K_TRUE, dist)
    assert fit.rejected.size == 0
    # Same ML optimum as solvePnP with the same distortion (0.1 mm), and near the truth.
    assert np.linalg.norm(_centre(fit) - pnp) < 1e-4
    assert np.linalg.norm(_centre(fit) + R.T @ t) < 0.02
    assert fit.rms < 0.6


def test_points_above_the_floor_are_used():
    R, t = _ceiling_camera()
    rng = np.random.default_rng(5)
    X, _ = _floor_points(rng, 8, R, t)
    X[:3, 2] = [0.75, 0.9, 1.1]  # a table, a shelf, a window sill
    uv, _ = cv2.projectPoints(X, cv2.Rodrigues(R)[0], t, K_TRUE, None)
    fit = place_camera(X, uv[:, 0], SIZE)
    assert abs(fit.K[0, 0] - 600.0) < 0.01
    assert np.linalg.norm(_centre(fit) + R.T @ t) < 1e-5


def test_degenerate_input_is_refused_with_a_reason():
    R, t = _ceiling_camera()
    X, uv = _floor_points(np.random.default_rng(1), 6, R, t)
    with pytest.raises(NotEnoughPoints):
        place_camera(X[:3], uv[:3], SIZE)
    line = np.stack([np.linspace(1, 4, 6), np.linspace(1, 3, 6), np.zeros(6)], 1)
    line_px = cv2.projectPoints(line, cv2.Rodrigues(R)[0], t, K_TRUE, None)[0][:, 0]
    with pytest.raises(DegenerateConfiguration, match="line"):
        place_camera(line, line_px, SIZE)
    spot = np.array([2.0, 2.0, 0.0]) + np.random.default_rng(2).normal(0, 0.005, (6, 3)) * [
        1,
        1,
        0,
    ]
    with pytest.raises(DegenerateConfiguration, match="one spot"):
        place_camera(spot, uv, SIZE)


def test_pets2009_camera_placed_from_ground_truth_floor_points(shared_data_dir):
    gt = np.loadtxt(shared_data_dir / "pets2009-s2l1" / "gt-frames-001-400.txt", delimiter=",")
    gt = gt[gt[:, 6] == 1]
    frame = gt[:, 0]
    pixel = np.stack([gt[:, 2] + gt[:, 4] / 2, gt[:, 3] + gt[:, 5]], 1)
    floor = gt[:, 7:9]
    given = np.isin(frame, np.arange(1, 400, 50))  # 8 frames, 45 people's feet
    fit = place_camera(floor[given], pixel[given], (768, 576))
    R = fit.T_world_camera[:3, :3].T
    t = -R @ fit.T_world_camera[:3, 3]
    other = np.c_[floor[~given], np.zeros((~given).sum())]
    proj = cv2.projectPoints(other, cv2.Rodrigues(R)[0], t, fit.K, None)[0][:, 0]
    median = float(np.median(np.linalg.norm(proj - pixel[~given], axis=1)))
    print(
        f"PETS: f {fit.K[0, 0]:.1f} +- {fit.std_f_px:.1f} px, height "
        f"{fit.T_world_camera[2, 3]:.3f} m, median on {(~given).sum()} other points {median:.3f} px"
    )
    assert median <= 1.0  # spec 08's acceptance
    # The README's camera: f near 1180 px, about 7.1 m up; within 3 reported std (or 1 %).
    assert abs(fit.K[0, 0] - 1180.0) < max(3 * fit.std_f_px, 12.0)
    assert abs(fit.T_world_camera[2, 3] - 7.1) < 0.15
