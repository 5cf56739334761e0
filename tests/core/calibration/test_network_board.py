"""Network calibration of the board kind: a chessboard on the robot seen by the cameras gives
their intrinsics, distortion and poses; cameras with too few views are rejected by name."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInput
from core.geometry.rotations import matrix_to_rotvec
from core.localization import NetworkCamera
from tests.support.camera_network import DIST, network

BOARD_TILT = 0.5


def _board() -> tuple[np.ndarray, np.ndarray]:
    """Model points (24, 3) of a 6 x 4 board of 8 cm squares and its mounting T_robot_board:
    tilted forward and up by BOARD_TILT about the robot's y axis, grid centred 0.5 m up."""
    from core.calibration import Chessboard, board_object_points

    P = board_object_points(Chessboard(6, 4), 0.08)
    u = np.array([0.0, 1.0, 0.0])
    v = np.array([np.cos(BOARD_TILT), 0.0, -np.sin(BOARD_TILT)])
    T = np.eye(4)
    T[:3, :3] = np.column_stack([u, v, np.cross(u, v)])
    T[:3, 3] = np.array([0.0, 0.0, 0.5]) - u * 0.2 - v * 0.12
    return P, T


def _board_views(cams: list[NetworkCamera], n: int, sigma: float, seed: int):
    """Return robot poses (n, 3), corners (C, n, 24, 2) with N(0, sigma^2) noise and whether
    each camera sees the whole board's printed face (C, n)."""
    rng = np.random.default_rng(seed)
    P, T_rb = _board()
    poses = np.column_stack(
        [rng.uniform(0.5, 3.8, n), rng.uniform(0.5, 3.5, n), rng.uniform(-np.pi, np.pi, n)]
    )
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    R = np.zeros((n, 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    B = P @ T_rb[:3, :3].T + T_rb[:3, 3]  # (24, 3) robot frame
    X = np.einsum("nij,kj->nki", R, B)
    X[..., :2] += poses[:, None, :2]
    face = -(R @ T_rb[:3, 2])  # printed face's normal, (n, 3)
    uv = np.zeros((len(cams), n, len(P), 2))
    vis = np.zeros((len(cams), n), bool)
    for k, cam in enumerate(cams):
        toward = np.einsum("ni,ni->n", face, cam.center - X.mean(1)) > 0
        inside = cam.in_view(X.reshape(-1, 3)).reshape(n, len(P)).all(1)
        vis[k] = toward & inside
        uv[k] = cam.project(X.reshape(-1, 3)).reshape(n, len(P), 2)
    return poses, uv + sigma * rng.standard_normal(uv.shape), vis


def test_board_kind_recovers_intrinsics_distortion_and_poses() -> None:
    from core.calibration.network import calibrate_network_board

    cams = network()
    P, T_rb = _board()
    poses, uv, vis = _board_views(cams, 160, 0.1, 11)
    # Half the views in the detector's other corner order (a half turn of the grid), and a
    # mirrored order in one view of camera a: the vote must turn the first back, drop the other.
    uv[:, 1::2] = uv[:, 1::2, ::-1]
    j = np.flatnonzero(vis[0])[0]
    uv[0, j] = uv[0, j].reshape(4, 6, 2)[::-1].reshape(24, 2)
    net = calibrate_network_board(
        [c.name for c in cams], [(640, 480)] * 3, uv, vis, P, T_rb, poses, pixel_sigma=0.1
    )
    assert not net.rejected
    for cal, true in zip(net.cameras, cams, strict=True):
        assert cal.poses_seen >= 20, cal.poses_seen
        # 0.1 px noise on >= 20 views of 24 corners: focal to 0.2 %, principal point to 1 px,
        # the centre to 5 mm and the orientation to 0.05 deg (a few standard deviations).
        assert abs(cal.focal / 330.0 - 1) < 2e-3
        assert np.linalg.norm(cal.K[:2, 2] - [320, 240]) < 1.0
        assert np.linalg.norm(cal.position - true.center) < 5e-3
        ang = np.degrees(np.linalg.norm(matrix_to_rotvec(cal.R @ true.R.T)))
        assert ang < 0.05
        # k1, k2 of a strong barrel lens within a few percent; the fit is at the noise.
        np.testing.assert_allclose(cal.dist[:2], DIST[:2], rtol=0.1)
        assert cal.rms < 0.15
        assert cal.parameter_names[:4] == ("fx", "fy", "cx", "cy")
        assert len(cal.std) == len(cal.parameter_names)
    assert net.camera("a").outliers >= 1
    assert net.targets.shape == (160, 3)


def test_board_kind_rejects_a_camera_with_too_few_views_by_name() -> None:
    from core.calibration.network import calibrate_network_board

    cams = network()
    P, T_rb = _board()
    poses, uv, vis = _board_views(cams, 120, 0.1, 12)
    vis[1, np.flatnonzero(vis[1])[5:]] = False
    net = calibrate_network_board(
        [c.name for c in cams],
        [(640, 480)] * 3,
        uv,
        vis,
        P,
        T_rb,
        poses,
        pose_sigma=(0.002, 0.003),
        min_views=8,
    )
    assert [r.name for r in net.rejected] == ["b"]
    assert "too few board views: saw 5" in net.rejected[0].reason
    assert {c.name for c in net.cameras} == {"a", "c"}
    assert net.target_cov.shape == (120, 3, 3)
    with pytest.raises(InvalidInput, match="too few board views"):
        net.camera("b")


def test_board_kind_checks_its_inputs() -> None:
    from core.calibration.network import calibrate_network_board

    P, T_rb = _board()

    def calibrate_one_camera(corners: np.ndarray, **options: str) -> None:
        # One camera, five views of the board from the origin.
        calibrate_network_board(
            ["a"],
            [(640, 480)],
            corners,
            np.ones((1, 5), bool),
            P,
            T_rb,
            np.zeros((5, 3)),
            **options,
        )

    with pytest.raises(InvalidInput):
        calibrate_one_camera(np.zeros((1, 5, 23, 2)))
    with pytest.raises(InvalidInput, match="distortion"):
        calibrate_one_camera(np.zeros((1, 5, 24, 2)), distortion="fisheye")
