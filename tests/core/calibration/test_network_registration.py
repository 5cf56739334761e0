"""Registering a camera network to the world by points known in both frames: the floor rigid
motion against its truth, its covariance against the scatter of many draws, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from core.calibration.network import register_planar
from core.errors import DegenerateConfiguration, InvalidInput


def _rot(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


def _pairs(rng: np.random.Generator, k: int = 6):
    """K world points over a home's floor, their covariances (anisotropic, as a signpost read
    gives: 3-40 mm) and the network's (10 mm), for a true motion of 0.7 deg and 4 cm."""
    theta, t = math.radians(0.7), np.array([0.03, -0.02])
    w = rng.uniform([3.5, 0.5], [7.5, 5.5], size=(k, 2))
    a = rng.uniform(0, np.pi, k)
    sd = np.column_stack([rng.uniform(0.003, 0.01, k), rng.uniform(0.02, 0.04, k)])
    Cw = np.array([_rot(ai) @ np.diag(s**2) @ _rot(ai).T for ai, s in zip(a, sd, strict=True)])
    Cn = np.tile(np.eye(2) * 0.01**2, (k, 1, 1))
    n = (w - t) @ _rot(theta)  # n = R^T (w - t): w = R n + t exactly
    return theta, t, n, Cn, w, Cw


def test_exact_pairs_give_the_motion():
    rng = np.random.default_rng(3)
    theta, t, n, Cn, w, Cw = _pairs(rng)
    reg = register_planar(n, Cn, w, Cw)
    assert reg.theta == pytest.approx(theta, abs=1e-12)
    np.testing.assert_allclose(reg.t, t, atol=1e-12)
    np.testing.assert_allclose(reg.residuals, 0.0, atol=1e-12)
    # The 4 x 4 form applies it to points at any height.
    p = np.array([n[0, 0], n[0, 1], 1.7, 1.0])
    np.testing.assert_allclose((reg.matrix @ p)[:2], w[0], atol=1e-12)


def test_the_covariance_agrees_with_the_scatter():
    """500 noisy draws with known covariances: the normalised estimation error squared of
    (theta, tx, ty) averages 3 (its chi-square expectation) within the 99 % interval of the
    mean of 500 chi-square(3) draws. The scaled covariance (K > 2) is floored at the claim, so
    it is compared with that claim here: noise exactly as claimed."""
    rng = np.random.default_rng(7)
    theta, t, n, Cn, w, Cw = _pairs(rng)
    nees = []
    for _ in range(500):
        wn = w + np.array([rng.multivariate_normal([0, 0], C) for C in Cw])
        nn = n + np.array([rng.multivariate_normal([0, 0], C) for C in Cn])
        reg = register_planar(nn, Cn, wn, Cw)
        e = np.array([reg.theta - theta, *(reg.t - t)])
        nees.append(float(e @ np.linalg.solve(reg.cov, e)))
    lo, hi = chi2.ppf([0.005, 0.995], 3 * 500) / 500
    # The scale floor (max(chi2 / dof, 1)) only ever widens the claim: NEES at or below 3.
    assert lo * 0.8 < np.mean(nees) < hi, np.mean(nees)


def test_points_that_fix_no_heading_are_refused():
    rng = np.random.default_rng(1)
    _, _, n, Cn, w, Cw = _pairs(rng, 2)
    with pytest.raises(DegenerateConfiguration, match="at least 2"):
        register_planar(n[:1], Cn[:1], w[:1], Cw[:1])
    close = np.array([[4.0, 3.0], [4.2, 3.1]])
    with pytest.raises(DegenerateConfiguration, match="heading"):
        register_planar(close, Cn, close, Cw)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"network_xy": [[0.0, np.nan], [1.0, 1.0]]}, "NaN"),
        ({"network_xy": [[0.0, 0.0, 0.0]]}, "shape"),
        ({"world_cov": np.zeros((2, 2, 2))}, "positive definite"),
        ({"network_cov": np.eye(2)}, "covariances"),
    ],
)
def test_bad_input_is_refused_by_name(kwargs, message):
    args = {
        "network_xy": [[0.0, 0.0], [3.0, 1.0]],
        "network_cov": np.tile(np.eye(2) * 1e-4, (2, 1, 1)),
        "world_xy": [[0.0, 0.0], [3.0, 1.0]],
        "world_cov": np.tile(np.eye(2) * 1e-4, (2, 1, 1)),
    }
    args.update(kwargs)
    with pytest.raises(InvalidInput, match=message):
        register_planar(**args)
