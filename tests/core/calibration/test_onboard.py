"""The onboard camera's floor plane from one view, and spots back-projected onto it."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from core.calibration.onboard import calibrate_floor_plane, floor_plane_from_mount
from core.errors import DegenerateConfiguration

K = np.array([[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]])
DIST = np.array([-0.05, 0.01, 0.0, 0.0, 0.0])


def _mount(pitch_deg: float = 40.0, height: float = 0.4) -> np.ndarray:
    """T_robot_cam of a camera 0.15 m ahead of the axle, `height` up, pitched down."""
    p = math.radians(pitch_deg)
    z = np.array([math.cos(p), 0.0, -math.sin(p)])
    x = np.array([0.0, -1.0, 0.0])
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = [0.15, 0.0, height]
    return T


def _view(T_robot_cam: np.ndarray, pts: np.ndarray) -> np.ndarray:
    T = np.linalg.inv(T_robot_cam)
    rvec, _ = cv2.Rodrigues(T[:3, :3])
    uv, _ = cv2.projectPoints(pts, rvec, T[:3, 3], K, DIST)
    return uv.reshape(-1, 2)


def _pattern() -> np.ndarray:
    # A 7 x 5 floor pattern of 0.1 m squares, 0.5 to 1.1 m ahead of the robot.
    gx, gy = np.meshgrid(0.5 + 0.1 * np.arange(7), 0.1 * (np.arange(5) - 2))
    return np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])


@pytest.mark.parametrize("pitch", [25.0, 40.0, 55.0])
def test_floor_plane_from_one_view_is_within_spec(pitch: float) -> None:
    T = _mount(pitch)
    n_true = np.linalg.inv(T)[:3, 2]
    d_true = abs(float(n_true @ np.linalg.inv(T)[:3, 3]))
    pattern = _pattern()
    clean = _view(T, pattern)
    worst_n = worst_d = 0.0
    for seed in range(20):
        # 0.2 px: a chessboard corner refined by cv2.cornerSubPix on a rendered image.
        uv = clean + np.random.default_rng(seed).normal(0.0, 0.2, clean.shape)
        plane = calibrate_floor_plane(pattern, uv, K, DIST)
        cos = abs(float(plane.normal @ n_true))
        worst_n = max(worst_n, math.degrees(math.acos(min(1.0, cos))))
        worst_d = max(worst_d, abs(plane.distance - d_true))
    # Spec 03: normal within 0.2 deg, distance within 2 mm, in every trial.
    assert worst_n < 0.2
    assert worst_d < 0.002


def test_back_projection_returns_the_floor_point_in_the_robot_frame() -> None:
    T = _mount()
    pts = np.array([[0.4, 0.2, 0.0], [1.2, -0.3, 0.0], [0.8, 0.0, 0.0]])
    uv = _view(T, pts)
    exact = floor_plane_from_mount(T, K, DIST)
    np.testing.assert_allclose(exact.to_robot(uv), pts[:, :2], atol=1e-9)
    fitted = calibrate_floor_plane(_pattern(), _view(T, _pattern()), K, DIST)
    np.testing.assert_allclose(fitted.to_robot(uv), pts[:, :2], atol=1e-7)
    # A pixel above the floor's horizon has no floor point.
    assert np.isnan(exact.to_robot([[319.5, -400.0]])).all()


def test_collinear_pattern_points_are_refused() -> None:
    line = np.column_stack([0.5 + 0.1 * np.arange(6), np.zeros(6), np.zeros(6)])
    with pytest.raises(DegenerateConfiguration):
        calibrate_floor_plane(line, _view(_mount(), line), K, DIST)
