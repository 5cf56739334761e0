"""Ellipse fits and circle geometry against exact projections and OpenCV."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from core.errors import DegenerateConfiguration
from core.geometry.rotations import rotvec_to_matrix
from core.landmarks.conics import (
    ConicFit,
    circle_distance,
    circle_normals,
    concentric_centre,
    fit_ellipse,
    fit_ellipses,
)

K = np.array([[600.0, 0, 320], [0, 600, 240], [0, 0, 1]])
# A circle plane turned 60 deg away from the camera, off the optical axis: strong perspective.
R = rotvec_to_matrix([0.0, np.radians(60), 0.0]) @ rotvec_to_matrix([np.pi, 0, 0])
T = np.array([0.15, -0.1, 0.5])


def _circle_px(radius: float, n: int = 400) -> np.ndarray:
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    X = np.stack([radius * np.cos(a), radius * np.sin(a), 0 * a], 1) @ R.T + T
    u = X @ K.T
    return u[:, :2] / u[:, 2:]


def _true_centre_px() -> np.ndarray:
    u = K @ T
    return u[:2] / u[2]


def test_fit_ellipse_matches_opencv_and_exact_points() -> None:
    pts = _circle_px(0.1)
    fit = fit_ellipse(pts)
    # Exact points: every Sampson distance ~0 (the conic through them is exact).
    assert fit.rms < 1e-6
    rng = np.random.default_rng(3)
    noisy = pts + rng.normal(0, 0.2, pts.shape)
    fit = fit_ellipse(noisy)
    (cx, cy), _, _ = cv2.fitEllipse(noisy.astype(np.float32))
    # Both fit the same ellipse: centres agree to a small fraction of a pixel (400 points,
    # 0.2 px noise: the centre's standard error is ~0.02 px).
    assert np.linalg.norm(fit.centre - [cx, cy]) < 0.1
    # The RMS Sampson distance estimates the noise (0.2 px per coordinate, normal component).
    assert fit.rms == pytest.approx(0.2, rel=0.15)
    with pytest.raises(DegenerateConfiguration):
        fit_ellipse(np.column_stack([np.arange(10.0), 2 * np.arange(10.0)]))


def test_fit_ellipses_batch_fits_each_set_as_alone() -> None:
    rng = np.random.default_rng(5)
    # Sets of different sizes (the shorter ones padded in the batch) and a collinear one.
    radii = (0.1, 0.06, 0.08)
    sets = [
        _circle_px(r, n) + rng.normal(0, 0.2, (n, 2))
        for r, n in zip(radii, (400, 150, 37), strict=True)
    ]
    line = np.column_stack([np.arange(10.0), 2 * np.arange(10.0)])
    batch = fit_ellipses([sets[0], line, sets[1], sets[2]])
    assert isinstance(batch[1], str) and "collinear" in batch[1]
    for r, pts, fit in zip(radii, sets, (batch[0], batch[2], batch[3]), strict=True):
        assert isinstance(fit, ConicFit)
        alone = fit_ellipse(pts)
        # The same Gauss-Newton iterates: only the summation order differs (padding zeros),
        # so the conics (unit Frobenius norm) agree to rounding. A set that stops before the
        # others has its Jacobian taken at its last iterate rather than the one before, a
        # step under 1e-7 away: its covariance moves by about that fraction.
        assert np.abs(fit.C - alone.C).max() < 1e-12
        assert np.abs(fit.cov - alone.cov).max() < 1e-6 * np.abs(alone.cov).max()
        assert fit.rms == pytest.approx(alone.rms, rel=1e-9)
        assert fit.n == len(pts)
        # And each is its circle's ellipse: the centre within a few standard errors (0.2 px
        # noise, >= 37 points: < 0.1 px) of the exact image's ellipse centre.
        assert np.linalg.norm(fit.centre - fit_ellipse(_circle_px(r)).centre) < 0.3


def test_pencil_centre_removes_the_ellipse_centre_bias() -> None:
    rng = np.random.default_rng(0)
    outer = fit_ellipse(_circle_px(0.1) + rng.normal(0, 0.1, (400, 2)))
    inner = fit_ellipse(_circle_px(0.06) + rng.normal(0, 0.1, (400, 2)))
    truth = _true_centre_px()
    c = concentric_centre(K.T @ outer.C @ K, K.T @ inner.C @ K)
    pencil_err = np.linalg.norm((K @ c)[:2] - truth)
    naive_err = np.linalg.norm(outer.centre - truth)
    # The ellipse centre is biased by perspective (here several pixels); the pencil's centre is
    # the true projection, off only by the fit noise (0.1 px on 400 points: ~0.05 px).
    assert naive_err > 2.0
    assert pencil_err < 0.1
    assert pencil_err < naive_err / 20


def test_circle_normals_and_distance() -> None:
    Q = K.T @ fit_ellipse(_circle_px(0.1)).C @ K
    n_true = R[:, 2] if R[:, 2] @ T < 0 else -R[:, 2]
    na, nb = circle_normals(Q)
    errs = sorted(np.degrees(np.arccos(np.clip([na @ n_true, nb @ n_true], -1, 1))))
    assert errs[0] < 1e-4  # one candidate is exact (noise-free points)
    assert errs[1] > 10  # the other is the mirrored one, far from it at 60 deg obliquity
    n = na if na @ n_true > nb @ n_true else nb
    m = T / T[2]
    assert circle_distance(Q, n, m, 0.1) * m == pytest.approx(T, abs=1e-9)


def test_circle_functions_take_stacks_as_one_at_a_time() -> None:
    # The detector's sigma points go through them in one stack; each row must be what the
    # single call gives, and one degenerate row must not pass unnoticed.
    rng = np.random.default_rng(5)
    Q1 = K.T @ fit_ellipse(_circle_px(0.1)).C @ K
    Q2 = K.T @ fit_ellipse(_circle_px(0.06)).C @ K
    Q1s = np.array([Q1 + rng.normal(0, 1e-4 * np.abs(Q1).max(), (3, 3)) for _ in range(5)])
    Q1s = 0.5 * (Q1s + np.swapaxes(Q1s, 1, 2))
    Q2s = np.broadcast_to(Q2, Q1s.shape)
    m = concentric_centre(Q1s, Q2s)
    na, nb = circle_normals(Q1s)
    d = circle_distance(Q1s, na, m, 0.1)
    assert m.shape == na.shape == nb.shape == (5, 3) and np.shape(d) == (5,)
    for i in range(5):
        assert np.allclose(m[i], concentric_centre(Q1s[i], Q2s[i]), atol=1e-12)
        a1, b1 = circle_normals(Q1s[i])
        assert np.allclose(na[i], a1, atol=1e-12) and np.allclose(nb[i], b1, atol=1e-12)
        assert d[i] == pytest.approx(circle_distance(Q1s[i], a1, m[i], 0.1), rel=1e-12)
    bad = Q1s.copy()
    bad[2] = np.diag([1.0, 1.0, 1.0])  # no real points: not the image of a circle
    with pytest.raises(DegenerateConfiguration):
        circle_normals(bad)
