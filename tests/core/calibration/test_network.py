"""Network calibration from a marker on the floor plane: synthetic projections of known cameras."""

from __future__ import annotations

import numpy as np
import pytest

from core.calibration.network import calibrate_network_marker
from core.errors import InvalidInput
from core.localization import NetworkCamera

K = np.array([[330.0, 0.0, 320.0], [0.0, 330.0, 240.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.28, 0.07, 0.0005, -0.0004, -0.002])
H = 0.36


def _network() -> list[NetworkCamera]:
    return [
        NetworkCamera.looking_at(K, DIST, [0.3, 0.3, 2.8], [2.3, 2.0, 0.0], (640, 480), "a"),
        NetworkCamera.looking_at(K, DIST, [4.2, 3.7, 2.8], [2.0, 1.8, 0.0], (640, 480), "b"),
        NetworkCamera.looking_at(K, DIST, [4.2, 0.2, 2.8], [2.2, 2.0, 0.0], (640, 480), "c"),
    ]


def _observe(cams: list[NetworkCamera], xy: np.ndarray, sigma: float, seed: int):
    rng = np.random.default_rng(seed)
    X = np.column_stack([xy, np.full(len(xy), H)])
    vis = np.stack([c.in_view(X) for c in cams])
    px = np.stack([c.project(X) for c in cams]) + sigma * rng.standard_normal(
        (len(cams), len(xy), 2)
    )
    return px, vis


def _grid() -> np.ndarray:
    g = np.stack(np.meshgrid(np.linspace(0.5, 3.8, 8), np.linspace(0.5, 3.5, 7)), -1)
    return g.reshape(-1, 2)


def test_recovers_the_cameras_from_noisy_detections() -> None:
    cams = _network()
    xy = _grid()
    px, vis = _observe(cams, xy, 0.1, 3)
    net = calibrate_network_marker(
        [c.name for c in cams], [K[:2, 2]] * 3, [DIST] * 3, px, vis, xy, H, pixel_sigma=0.1
    )
    assert not net.rejected
    for cal, true in zip(net.cameras, cams, strict=True):
        # 0.1 px noise on ~50 points over a wide view: focal to ~0.1 %, centre to a few mm.
        assert abs(cal.focal / 330.0 - 1) < 3e-3
        assert np.linalg.norm(cal.position - true.center) < 0.01
        assert cal.rms < 0.2
        assert np.all(cal.std > 0)


def test_cameras_with_too_few_or_collinear_poses_are_reported_by_name() -> None:
    cams = _network()
    xy = _grid()
    px, vis = _observe(cams, xy, 0.1, 4)
    vis[0, np.flatnonzero(vis[0])[3:]] = False  # camera a: three poses only
    line = np.abs(xy[:, 1] - xy[3, 1]) < 1e-9  # camera b: one straight row of the grid
    vis[1] &= line
    net = calibrate_network_marker(
        [c.name for c in cams], [K[:2, 2]] * 3, [DIST] * 3, px, vis, xy, H, min_poses=4
    )
    reasons = {r.name: r.reason for r in net.rejected}
    assert set(reasons) == {"a", "b"}
    assert "too few poses" in reasons["a"]
    assert "collinear" in reasons["b"]
    assert [c.name for c in net.cameras] == ["c"]
    assert abs(net.camera("c").focal / 330.0 - 1) < 5e-3
    with pytest.raises(InvalidInput, match="too few poses"):
        net.camera("a")


def test_free_targets_with_a_prior_stay_near_the_recorded_poses() -> None:
    cams = _network()
    xy = _grid()
    rng = np.random.default_rng(5)
    true_xy = xy + 0.003 * rng.standard_normal(xy.shape)
    px, vis = _observe(cams, true_xy, 0.05, 6)
    net = calibrate_network_marker(
        [c.name for c in cams],
        [K[:2, 2]] * 3,
        [DIST] * 3,
        px,
        vis,
        xy,
        H,
        pixel_sigma=0.05,
        target_sigma=0.003,
    )
    # The refined targets are closer to the truth than the recorded ones.
    before = np.sqrt(np.mean(np.sum((xy - true_xy) ** 2, 1)))
    after = np.sqrt(np.mean(np.sum((net.targets - true_xy) ** 2, 1)))
    assert after < before
    assert net.target_cov.shape == (len(xy), 2, 2)


def test_shapes_are_checked() -> None:
    with pytest.raises(InvalidInput):
        calibrate_network_marker(
            ["a"],
            [[320, 240]],
            [DIST],
            np.zeros((2, 5, 2)),
            np.ones((2, 5), bool),
            np.zeros((5, 2)),
            H,
        )
