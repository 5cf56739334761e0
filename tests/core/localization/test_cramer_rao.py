"""The Cramer-Rao bound: closed form, independent Jacobians, and Monte Carlo of the ML estimate."""

from __future__ import annotations

import numpy as np
import pytest
from localization_scene import floor_points, make_cameras

from core.errors import InvalidInput
from core.localization import NetworkCamera, cramer_rao_bound, locate_ml


def test_bound_of_a_camera_looking_straight_down_is_closed_form():
    # No distortion, optical axis vertical: u = f X / (H - h) + c, so J = f / (H - h) I and
    # CRB = sigma^2 (H - h)^2 / f^2 I exactly.
    f, H, h, sigma = 700.0, 3.0, 0.5, 0.8
    K = np.array([[f, 0.0, 320.0], [0.0, f, 240.0], [0.0, 0.0, 1.0]])
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = [1.0, 2.0, H]
    cam = NetworkCamera.from_pose(K, None, T, (640, 480))
    b = cramer_rao_bound([cam], [1.0, 2.0], h, pixel_sigma=sigma)
    expected = (sigma * (H - h) / f) ** 2
    assert np.allclose(b.cov, expected * np.eye(2), rtol=1e-12, atol=0)
    assert b.n_cameras == 1 and b.std == pytest.approx(np.sqrt(2 * expected), rel=1e-12)


def test_fisher_information_uses_the_true_projection_jacobian():
    # Independent check of the analytic J through central differences of the projection.
    cams = make_cameras(4)
    rng = np.random.default_rng(4)
    P = floor_points(rng, 200, 0.3)
    vis = np.stack([c.in_view(P) for c in cams])
    b = cramer_rao_bound(cams, P[:, :2], 0.3, pixel_sigma=1.0, visible=vis)
    step = 1e-6  # metres; central-difference error ~ step^2 * u''' ~ 1e-9 relative
    info = np.zeros((len(P), 2, 2))
    for k, cam in enumerate(cams):
        J = np.empty((len(P), 2, 2))
        for a in range(2):
            d = np.zeros(3)
            d[a] = step
            J[:, :, a] = (cam.project(P + d) - cam.project(P - d)) / (2 * step)
        info += np.where(vis[k][:, None, None], J.transpose(0, 2, 1) @ J, 0.0)
    ref = np.linalg.inv(info)
    scale = np.max(np.abs(ref), axis=(1, 2), keepdims=True)
    assert np.all(np.abs(b.cov - ref) <= 1e-6 * scale)


def test_more_cameras_never_loosen_the_bound_and_unseen_targets_are_unbounded():
    cams = make_cameras(4)
    xy = np.array([[4.0, 3.0], [6.5, 1.0], [-5.0, -5.0]])
    prev = None
    for n in range(1, 5):
        vis = np.zeros((n, 3), dtype=bool)
        vis[:, :2] = True
        b = cramer_rao_bound(cams[:n], xy, 0.3, pixel_sigma=0.5, visible=vis)
        if prev is not None:
            assert np.all(b.std[:2] <= prev + 1e-15)
        prev = b.std[:2]
        assert np.isinf(b.std[2]) and np.all(np.isnan(b.cov[2]))
    # Default visibility: the last target is behind camera 0.
    b = cramer_rao_bound(cams[:1], xy, 0.3, pixel_sigma=0.5)
    assert b.n_cameras.tolist() == [1, 1, 0] and np.isinf(b.std[2])
    assert np.isfinite(b.root_mean_trace)


def test_bound_rejects_malformed_input():
    cams = make_cameras(2)
    with pytest.raises(InvalidInput, match="xy"):
        cramer_rao_bound(cams, [[1.0, 2.0, 3.0]])
    with pytest.raises(InvalidInput, match="NaN"):
        cramer_rao_bound(cams, [[np.nan, 2.0]])
    with pytest.raises(InvalidInput, match="visible"):
        cramer_rao_bound(cams, [[1.0, 2.0]], visible=np.ones((3, 1), dtype=bool))
    with pytest.raises(InvalidInput, match="pixel_sigma"):
        cramer_rao_bound(cams, [[1.0, 2.0]], pixel_sigma=-1.0)


# Targets seen by 2, 3 and 4 cameras, each located T times with fresh noise. The sample
# covariance of T Gaussian draws has a trace with relative sd sqrt(2 tr(C^2)) / (tr C sqrt(T))
# <= sqrt(2 / T) = 1.6 % at T = 8000; 6 % is > 3.7 sd. The ML estimate's bias at sigma = 0.5 px
# is O(sigma^2) ~ 1e-5 m, negligible against its ~4 mm spread.
T_TRIALS = 8000


def test_bound_matches_the_ml_scatter():
    cams = make_cameras(4)
    sigma, h = 0.5, 0.3
    rng = np.random.default_rng(31)
    candidates = floor_points(rng, 4000, h)
    vis_all = np.stack([c.in_view(candidates) for c in cams])
    picks = [int(np.flatnonzero(vis_all.sum(0) == n)[0]) for n in (2, 3, 4)]
    for j in picks:
        P = candidates[j]
        vis = np.repeat(vis_all[:, j : j + 1], T_TRIALS, axis=1)
        px = np.stack([c.project(P[None])[0] for c in cams])[:, None, :]
        px = px + rng.normal(0.0, sigma, (4, T_TRIALS, 2))
        ml = locate_ml(cams, px, h, visible=vis, pixel_sigma=sigma)
        bound = cramer_rao_bound(cams, P[:2], h, pixel_sigma=sigma, visible=vis_all[:, j])
        err = ml.xy - P[:2]
        sample = err.T @ err / T_TRIALS
        assert abs(np.trace(sample) / np.trace(bound.cov) - 1.0) < 0.06
        # The shape too: the whitened sample covariance is close to the identity (each entry
        # has sd ~ 1 / sqrt(T) = 0.011; 0.06 is > 5 sd).
        L = np.linalg.cholesky(bound.cov)
        W = np.linalg.solve(L, np.linalg.solve(L, sample).T)
        assert np.max(np.abs(W - np.eye(2))) < 0.06
        assert abs(err.mean(axis=0) @ err.mean(axis=0)) < 1e-2 * np.trace(bound.cov)
