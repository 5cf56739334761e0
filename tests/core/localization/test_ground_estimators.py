"""Floor estimators: exactness, typed errors, batch masks, and Monte Carlo against the bound."""

from __future__ import annotations

import numpy as np
import pytest
from localization_scene import floor_points, make_cameras, observe

from core.errors import DegenerateConfiguration, InvalidInput, NotEnoughPoints
from core.localization import (
    NetworkCamera,
    PointStatus,
    cramer_rao_bound,
    locate_ml,
    locate_monocular,
    triangulate_linear,
    triangulate_on_plane,
)

H = 0.3
# Noise-free estimates must reproduce the truth to 1e-9 m: the only error left is the
# round-off of undistortion (Newton to machine precision) and of small linear solves on
# metre-sized numbers, ~1e-14 m.
EXACT = 1e-9


@pytest.fixture(scope="module")
def cams() -> list[NetworkCamera]:
    return make_cameras(4)


@pytest.fixture(scope="module")
def noise_free(cams):
    rng = np.random.default_rng(11)
    P = floor_points(rng, 3000, H)
    px, vis = observe(cams, P, 0.0, None)
    return P, px, vis


def test_scene_is_a_two_to_four_camera_network(noise_free):
    _, _, vis = noise_free
    counts = np.bincount(vis.sum(axis=0), minlength=5)
    assert counts[0] == 0 and counts[1] == 0
    assert counts[2] > 0 and counts[3] > 0 and counts[4] > 0


def test_noise_free_batch_estimates_are_exact_with_distortion(cams, noise_free):
    P, px, vis = noise_free
    assert np.all(np.abs(cams[0].dist) > 0)
    lin = triangulate_linear(cams, px, visible=vis)
    con = triangulate_on_plane(cams, px, H, visible=vis)
    ml = locate_ml(cams, px, H, visible=vis)
    for est in (lin, con, ml):
        assert est.valid.all()
        assert np.max(np.abs(est.xy - P[:, :2])) < EXACT
        assert np.max(est.rms) < 1e-6  # pixels: reprojection of an exact point
    assert np.max(np.abs(lin.point - P)) < EXACT
    assert np.all(ml.point[:, 2] == H)
    for k, cam in enumerate(cams):
        mono = locate_monocular(cam, px[k, vis[k]], H)
        assert mono.valid.all()
        assert np.max(np.abs(mono.point - P[vis[k]])) < EXACT


def test_noise_free_single_target_forms_are_exact(cams, noise_free):
    P, px, vis = noise_free
    j = int(np.flatnonzero(vis.sum(axis=0) == 2)[0])
    used = [k for k in range(4) if vis[k, j]]
    sub = [cams[k] for k in used]
    for f in (triangulate_linear, triangulate_on_plane, locate_ml):
        kwargs = {} if f is triangulate_linear else {"height": H}
        est = f(sub, px[used, j], **kwargs)
        assert est.xy.shape == (2,) and est.cov.shape == (2, 2)
        assert est.status == PointStatus.OK and est.n_cameras == 2
        assert np.max(np.abs(est.xy - P[j, :2])) < EXACT
    # The whole network with a visibility mask gives the same point.
    est = locate_ml(cams, px[:, j], H, visible=vis[:, j])
    assert np.max(np.abs(est.xy - P[j, :2])) < EXACT
    mono = locate_monocular(sub[0], px[used[0], j], H)
    assert mono.xy.shape == (2,) and np.max(np.abs(mono.xy - P[j, :2])) < EXACT


def test_one_camera_constrained_and_ml_equal_monocular(cams, noise_free):
    # With one camera the two constrained equations are exact: the same point and covariance.
    rng = np.random.default_rng(5)
    _, px, vis = noise_free
    sel = vis[0]
    noisy = px[0, sel] + rng.normal(0, 0.5, (int(sel.sum()), 2))
    mono = locate_monocular(cams[0], noisy, H, pixel_sigma=0.5)
    con = triangulate_on_plane([cams[0]], noisy[None], H, pixel_sigma=0.5)
    ml = locate_ml([cams[0]], noisy[None], H, pixel_sigma=0.5)
    for est in (con, ml):
        assert np.max(np.abs(est.xy - mono.xy)) < 1e-9
        # Covariances agree to the relative round-off of two different linearisations.
        assert np.allclose(est.cov, mono.cov, rtol=1e-6, atol=0)


def test_single_target_errors_are_typed(cams, noise_free):
    _, px, vis = noise_free
    j = int(np.flatnonzero(vis[0])[0])
    with pytest.raises(NotEnoughPoints, match="at least 2"):
        triangulate_linear([cams[0]], px[:1, j])
    only0 = np.array([True, False, False, False])
    with pytest.raises(NotEnoughPoints, match="seen by 1 camera"):
        triangulate_on_plane(cams, px[:, j], H, visible=only0, min_cameras=2)
    with pytest.raises(NotEnoughPoints):
        locate_ml(cams, px[:, j], H, visible=np.zeros(4, dtype=bool))
    # The same camera twice: both rays coincide, the 3-D point is not fixed.
    with pytest.raises(DegenerateConfiguration, match="parallel"):
        triangulate_linear([cams[0], cams[0]], px[[0, 0], j])
    # A pixel above the horizon: its ray meets Z = h behind the camera.
    with pytest.raises(DegenerateConfiguration, match="behind"):
        locate_monocular(cams[0], [640.0, 5.0], H)
    with pytest.raises(DegenerateConfiguration, match="behind"):
        triangulate_on_plane([cams[0]], [[640.0, 5.0]], H)


def test_ray_parallel_to_the_plane_is_degenerate():
    K = np.array([[800.0, 0.0, 640.0], [0.0, 800.0, 400.0], [0.0, 0.0, 1.0]])
    level = NetworkCamera.looking_at(K, None, (0.0, 0.0, 1.5), (5.0, 0.0, 1.5), (1280, 800))
    # The principal point's ray is horizontal: it never meets Z = 0.
    with pytest.raises(DegenerateConfiguration, match="parallel to the plane"):
        locate_monocular(level, [640.0, 400.0], 0.0)
    with pytest.raises(DegenerateConfiguration):
        triangulate_on_plane([level], [[640.0, 400.0]], 0.0)


def test_batch_flags_bad_targets_instead_of_raising(cams, noise_free):
    P, px, vis = noise_free
    vis = vis.copy()
    vis[:, 0] = False  # target 0 unseen
    vis[1:, 1] = False  # target 1 seen by camera 0 only
    px = px.copy()
    px[:, 0] = np.nan  # unseen pixels may be NaN
    lin = triangulate_linear(cams, px, visible=vis)
    assert lin.status[0] == PointStatus.TOO_FEW_CAMERAS
    assert lin.status[1] == PointStatus.TOO_FEW_CAMERAS
    assert np.all(np.isnan(lin.point[:2])) and np.all(np.isnan(lin.cov[:2]))
    assert lin.valid[2:].all()
    ml = locate_ml(cams, px, H, visible=vis)
    assert ml.status[0] == PointStatus.TOO_FEW_CAMERAS and ml.valid[1:].all()
    assert np.max(np.abs(ml.xy[1:] - P[1:, :2])) < EXACT
    mono = locate_monocular(cams[0], [[640.0, 5.0], [640.0, 700.0]], H)
    assert mono.status.tolist() == [PointStatus.BEHIND_CAMERA, PointStatus.OK]


def test_malformed_input_raises_invalid_input(cams, noise_free):
    _, px, vis = noise_free
    with pytest.raises(InvalidInput, match="shape"):
        triangulate_on_plane(cams, px[:3], H)
    with pytest.raises(InvalidInput, match="shape"):
        triangulate_on_plane(cams, px[..., :1], H)
    bad = px.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(InvalidInput, match="NaN"):
        locate_ml(cams, bad, H)
    with pytest.raises(InvalidInput, match="boolean"):
        locate_ml(cams, px, H, visible=vis.astype(int))
    with pytest.raises(InvalidInput, match="pixel_sigma"):
        triangulate_linear(cams, px, visible=vis, pixel_sigma=0.0)
    with pytest.raises(InvalidInput, match="positive"):
        locate_ml(cams, px, H, visible=vis, pixel_cov=np.zeros((4, px.shape[1], 2, 2)))
    with pytest.raises(InvalidInput, match="height"):
        locate_ml(cams, px, float("nan"), visible=vis)
    with pytest.raises(InvalidInput, match="min_cameras"):
        triangulate_linear(cams, px, visible=vis, min_cameras=1)
    with pytest.raises(InvalidInput, match="NetworkCamera"):
        locate_ml(["cam"], px[:1], H)  # type: ignore[list-item]


# Monte Carlo. One noisy observation of each of N targets spread over the room, seen by 2-4
# cameras. For an efficient estimator e_b ~ N(0, C_b) (C_b the CRB of target b), so
# MSE = mean |e_b|^2 has mean mean(tr C_b) = RMT^2 and standard deviation
# sqrt(sum 2 tr(C_b^2)) / N. With N = 6000 that is ~1.5 % of the MSE here (0.75 % of the RMSE):
# a 5 % tolerance on RMSE / RMT is > 6 standard deviations, while a real inefficiency (the
# constrained estimator is ~5 % worse, the linear one ~20 %) is far outside the noise.
N_MC = 6000
SIGMA = 0.5


@pytest.fixture(scope="module")
def monte_carlo(cams):
    rng = np.random.default_rng(2024)
    P = floor_points(rng, N_MC, H)
    px, vis = observe(cams, P, SIGMA, rng)
    crb = cramer_rao_bound(cams, P[:, :2], H, pixel_sigma=SIGMA, visible=vis)
    est = {
        "linear": triangulate_linear(cams, px, visible=vis, pixel_sigma=SIGMA),
        "constrained": triangulate_on_plane(cams, px, H, visible=vis, pixel_sigma=SIGMA),
        "ml": locate_ml(cams, px, H, visible=vis, pixel_sigma=SIGMA),
    }
    return P, crb, est


def _rmse(err: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(err * err, axis=1))))


def test_ml_reaches_the_cramer_rao_bound(monte_carlo):
    P, crb, est = monte_carlo
    tr = np.trace(crb.cov, axis1=1, axis2=2)
    tr2 = np.trace(crb.cov @ crb.cov, axis1=1, axis2=2)
    mse_rel_sd = np.sqrt(np.sum(2.0 * tr2)) / np.sum(tr)
    # The tolerance below is statistically meaningful only if the sampling noise is far below
    # it: demand at least 4 standard deviations of RMSE (half the relative sd of the MSE).
    assert 4 * 0.5 * mse_rel_sd < 0.05
    ml = est["ml"]
    assert ml.valid.all()
    ratio = _rmse(ml.xy - P[:, :2]) / crb.root_mean_trace
    assert abs(ratio - 1.0) < 0.05


def test_constrained_beats_linear_and_ml_beats_constrained(monte_carlo):
    P, _, est = monte_carlo
    rmse = {k: _rmse(e.xy - P[:, :2]) for k, e in est.items()}
    # Differences of ~5 % and ~15 %, each > 6 sd of the sampling noise (see above).
    assert rmse["ml"] < rmse["constrained"] < rmse["linear"]


@pytest.mark.parametrize("method", ["linear", "constrained", "ml"])
def test_reported_covariance_matches_the_scatter(monte_carlo, method):
    P, _, est = monte_carlo
    e = est[method]
    err = e.xy - P[:, :2]
    d2 = np.einsum("bi,bij,bj->b", err, np.linalg.inv(e.cov), err)
    # If cov is right, d2 ~ chi^2(2): mean 2, sd of the mean 2 / sqrt(N) = 0.026; 0.13 = 5 sd.
    assert abs(d2.mean() - 2.0) < 0.13
    # And the tails: P(chi^2(2) > 5.991) = 5 %; binomial sd of the fraction 0.28 %.
    assert abs(np.mean(d2 > 5.991) - 0.05) < 0.015


def test_monocular_is_efficient_for_one_camera(cams):
    rng = np.random.default_rng(99)
    P = floor_points(rng, 20000, H)
    P = P[cams[2].in_view(P)][:N_MC]
    px = cams[2].project(P) + rng.normal(0, SIGMA, (len(P), 2))
    mono = locate_monocular(cams[2], px, H, pixel_sigma=SIGMA)
    crb = cramer_rao_bound([cams[2]], P[:, :2], H, pixel_sigma=SIGMA)
    # Monocular on the plane is ML for one camera, but its error grows with distance, so the
    # per-target bounds vary more than with 2-4 cameras: the sampling sd of the RMSE is ~1.5 %
    # here; 6 % is 4 sd.
    assert abs(_rmse(mono.xy - P[:, :2]) / crb.root_mean_trace - 1.0) < 0.06
    err = mono.xy - P[:, :2]
    d2 = np.einsum("bi,bij,bj->b", err, np.linalg.inv(mono.cov), err)
    assert abs(d2.mean() - 2.0) < 0.13


def test_per_detection_pixel_covariance_is_used(cams):
    # Anisotropic noise, different per camera: whitening by the right covariance keeps ML
    # efficient against the bound computed with the same covariances.
    rng = np.random.default_rng(7)
    n = 4000
    P = floor_points(rng, n, H)
    px, vis = observe(cams, P, 0.0, None)
    a = rng.uniform(0.2, 1.0, (4, n))
    b = rng.uniform(0.2, 1.0, (4, n))
    c = rng.uniform(-0.5, 0.5, (4, n)) * np.sqrt(a * b)
    S = np.stack([np.stack([a, c], -1), np.stack([c, b], -1)], -2)
    L = np.linalg.cholesky(S)
    px = px + np.einsum("cbij,cbj->cbi", L, rng.normal(size=(4, n, 2)))
    ml = locate_ml(cams, px, H, visible=vis, pixel_cov=S)
    crb = cramer_rao_bound(cams, P[:, :2], H, pixel_cov=S, visible=vis)
    err = ml.xy - P[:, :2]
    # sd of RMSE / RMT ~ 1 % at N = 4000; 5 % is > 4 sd.
    assert abs(_rmse(err) / crb.root_mean_trace - 1.0) < 0.05
    d2 = np.einsum("bi,bij,bj->b", err, np.linalg.inv(ml.cov), err)
    assert abs(d2.mean() - 2.0) < 0.16  # 2 / sqrt(4000) = 0.032; 5 sd
    con = triangulate_on_plane(cams, px, H, visible=vis, pixel_cov=S)
    d2c = np.einsum("bi,bij,bj->b", con.xy - P[:, :2], np.linalg.inv(con.cov), con.xy - P[:, :2])
    assert abs(d2c.mean() - 2.0) < 0.16


def test_ml_agrees_with_scipy_least_squares_per_target(cams):
    # Independent reference: each target's 2-parameter problem solved by SciPy's trust-region
    # least squares on the camera model's own projection (numerical Jacobian).
    from scipy.optimize import least_squares

    rng = np.random.default_rng(17)
    P = floor_points(rng, 40, H)
    px, vis = observe(cams, P, 2.0, rng)
    ml = locate_ml(cams, px, H, visible=vis, pixel_sigma=2.0)
    for j in range(len(P)):
        used = np.flatnonzero(vis[:, j])

        def residual(p, used=used, j=j):
            X = np.array([[p[0], p[1], H]])
            return np.concatenate([cams[k].project(X)[0] - px[k, j] for k in used])

        ref = least_squares(residual, P[j, :2], xtol=1e-15, ftol=1e-15, gtol=1e-15)
        # Both converge to the same minimum; the reference's own precision is ~1e-10 m.
        assert np.max(np.abs(ml.xy[j] - ref.x)) < 1e-8
        assert ml.rms[j] == pytest.approx(np.sqrt(np.mean(ref.fun**2)), rel=1e-6)


def test_chunked_batches_equal_one_pass(cams, monkeypatch):
    import core.localization.ground._batch as batch

    rng = np.random.default_rng(23)
    P = floor_points(rng, 50, H)
    px, vis = observe(cams, P, 0.5, rng)
    vis[:, 3] = False
    vis[1:, 4] = False
    whole = {
        "linear": triangulate_linear(cams, px, visible=vis),
        "constrained": triangulate_on_plane(cams, px, H, visible=vis),
        "ml": locate_ml(cams, px, H, visible=vis),
        "mono": locate_monocular(cams[0], px[0, vis[0]], H),
    }
    monkeypatch.setattr(batch, "_CHUNK", 7)
    parts = {
        "linear": triangulate_linear(cams, px, visible=vis),
        "constrained": triangulate_on_plane(cams, px, H, visible=vis),
        "ml": locate_ml(cams, px, H, visible=vis),
        "mono": locate_monocular(cams[0], px[0, vis[0]], H),
    }
    for key, a in whole.items():
        b = parts[key]
        assert np.array_equal(a.status, b.status) and np.array_equal(a.n_cameras, b.n_cameras)
        # Undistortion and the ML iterations stop on a whole chunk's largest step, so a chunk
        # may take one more or one fewer step: equal to their convergence tolerances.
        tol = 1e-9 if key == "ml" else 1e-12
        assert np.allclose(a.point, b.point, rtol=0, atol=tol, equal_nan=True)
        assert np.allclose(a.point_cov, b.point_cov, rtol=1e-6, atol=0, equal_nan=True)


def test_empty_batch_gives_empty_results(cams):
    px = np.zeros((4, 0, 2))
    for est in (
        triangulate_linear(cams, px),
        triangulate_on_plane(cams, px, H),
        locate_ml(cams, px, H),
        locate_monocular(cams[0], np.zeros((0, 2)), H),
    ):
        assert est.point.shape == (0, 3) and est.cov.shape == (0, 2, 2) and est.valid.shape == (0,)
