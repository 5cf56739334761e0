"""Decomposition of plane-induced homographies against ground truth and cv2.decomposeHomographyMat.

Noise-free data throughout: the decomposition is a closed form on a 3x3 SVD, so every recovered
quantity is exact up to rounding, O(eps * cond(H_e)) ~ 1e-14 here; 1e-9 is the acceptance level
of spec 01 ("noise-free data: every estimator exact to 1e-9") and leaves four orders of margin.
"""

from __future__ import annotations

from collections.abc import Iterator

import cv2
import numpy as np
import pytest

from core.errors import DegenerateConfiguration, InvalidInput
from core.geometry.rotations import rotvec_to_matrix
from core.homography.decompose import (
    CASE_ALONG_NORMAL,
    CASE_GENERAL,
    CASE_PURE_ROTATION,
    CASE_SINGULAR,
    PlaneMotion,
    decompose_homography,
    decompose_homography_batch,
)

EXACT = 1e-9
# OpenCV (Malis & Vargas) forms n from square roots of 2x2 minors of H_e^T H_e - I; on these
# configurations it agrees with ground truth to ~1e-12 (measured), so 1e-8 bounds the difference
# between two correct implementations with ample margin.
VS_OPENCV = 1e-8
W, HGT = 640, 480


def _random_K(rng: np.random.Generator) -> np.ndarray:
    f = rng.uniform(500.0, 1200.0)
    return np.array(
        [
            [f, rng.uniform(-1.0, 1.0), rng.uniform(280.0, 360.0)],
            [0.0, f * rng.uniform(0.9, 1.1), rng.uniform(200.0, 280.0)],
            [0.0, 0.0, 1.0],
        ]
    )


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _broad_config(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random R (any axis, up to ~100 deg), plane normal and t/d with d2/d = 1 + n^T R^T t > 0.1.

    |t/d| >= 0.1 keeps max |H_e^T H_e - I| far above the pure-rotation threshold 1e-3.
    """
    while True:
        R = rotvec_to_matrix(rng.normal(size=3) * 0.8)
        n = _unit(rng.normal(size=3))
        t = _unit(rng.normal(size=3)) * rng.uniform(0.1, 1.0)
        if 1.0 + n @ R.T @ t < 0:
            t = -t
        if 1.0 + n @ R.T @ t > 0.1:
            return R, t, n


def _look_at(direction: np.ndarray, roll: float) -> np.ndarray:
    """Return R (world -> camera) whose optical axis is `direction`, rolled by `roll`."""
    z = _unit(direction)
    x = _unit(np.cross([0.0, 1.0, 0.0], z))
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    c, s = np.cos(roll), np.sin(roll)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ R


def _visible_config(rng: np.random.Generator, K: np.ndarray, K2: np.ndarray, n_points: int = 30):
    """Two cameras looking at a plane; returns R, t/d, n and pixel points seen by both cameras."""
    while True:
        n = _unit(np.array([*rng.normal(size=2) * 0.5, 1.0]))  # faces camera 1 (n_z > 0.5)
        d = rng.uniform(1.0, 5.0)
        px = np.column_stack([rng.uniform(0, W, n_points), rng.uniform(0, HGT, n_points)])
        m1 = np.linalg.solve(K, np.column_stack([px, np.ones(n_points)]).T).T
        depth = d / (m1 @ n)
        px, m1, depth = px[depth > 0], m1[depth > 0], depth[depth > 0]
        X = m1 * depth[:, None]
        C2 = rng.normal(size=3) * 0.3 * d
        if n @ C2 > 0.7 * d:  # camera 2 must stay on the same side, not too close to the plane
            continue
        R = _look_at(X.mean(axis=0) - C2 + rng.normal(size=3) * 0.1 * d, rng.uniform(-0.5, 0.5))
        X2 = (X - C2) @ R.T
        front = X2[:, 2] > 0
        if front.sum() < 6:
            continue
        x2h = X2[front] @ K2.T
        px2 = x2h[:, :2] / x2h[:, 2:]
        t = -R @ C2 / d
        return R, t, n, px[front], px2


def _homography(R, t, n, K, K2=None, scale: float = 1.0) -> np.ndarray:
    K2 = K if K2 is None else K2
    return scale * K2 @ (R + np.outer(t, n)) @ np.linalg.inv(K)


def _random_homographies(rng: np.random.Generator, count: int) -> Iterator[tuple[np.ndarray, ...]]:
    """Yield `count` (R, t, n, K, H): a broad plane motion, random intrinsics and their
    homography at an arbitrary scale and sign (H is only defined up to a nonzero factor)."""
    for _ in range(count):
        R, t, n = _broad_config(rng)
        K = _random_K(rng)
        scale = rng.uniform(0.1, 10.0) * rng.choice([-1.0, 1.0])
        yield R, t, n, K, _homography(R, t, n, K, scale=scale)


def _dist(a: PlaneMotion, R, t, n) -> float:
    return float(max(np.abs(a.R - R).max(), np.abs(a.t - t).max(), np.abs(a.n - n).max()))


def _opencv(H: np.ndarray, K: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    _, Rs, ts, ns = cv2.decomposeHomographyMat(H, K)
    return [(R, t.ravel(), nn.ravel()) for R, t, nn in zip(Rs, ts, ns, strict=True)]


def test_truth_is_among_candidates_in_every_random_configuration():
    rng = np.random.default_rng(20260101)
    worst = 0.0
    for R, t, n, K, H in _random_homographies(rng, 500):
        sols = decompose_homography(H, K)
        assert len(sols) == 4
        assert all(s.case == "general" for s in sols)
        for s in sols:  # every candidate is a rotation and reproduces H_e exactly
            assert np.allclose(s.R @ s.R.T, np.eye(3), atol=1e-12)
            assert np.linalg.det(s.R) == pytest.approx(1.0, abs=1e-12)
            assert np.linalg.norm(s.n) == pytest.approx(1.0, abs=1e-12)
            assert np.allclose(s.R + np.outer(s.t, s.n), R + np.outer(t, n), atol=EXACT)
            assert s.distance_ratio > 0
        worst = max(worst, min(_dist(s, R, t, n) for s in sols))
    assert worst < EXACT


def test_same_candidate_set_as_opencv():
    rng = np.random.default_rng(7)
    worst = 0.0
    for _, _, _, K, H in _random_homographies(rng, 500):
        ours = decompose_homography(H, K)
        theirs = _opencv(H, K)
        assert len(ours) == len(theirs) == 4
        # One-to-one: the distance matrix must have a perfect matching below the tolerance, and
        # candidates are far apart (>= ~0.1), so a greedy nearest match is that matching.
        dist = np.array([[_dist(a, *b) for b in theirs] for a in ours])
        match = dist.argmin(axis=1)
        assert sorted(match) == [0, 1, 2, 3]
        worst = max(worst, dist.min(axis=1).max())
    assert worst < VS_OPENCV


def test_candidate_set_with_distinct_intrinsics():
    rng = np.random.default_rng(11)
    for _ in range(100):
        R, t, n = _broad_config(rng)
        K, K2 = _random_K(rng), _random_K(rng)
        sols = decompose_homography(_homography(R, t, n, K, K2, scale=-0.3), K, K2=K2)
        assert min(_dist(s, R, t, n) for s in sols) < EXACT


def _opencv_selection(H, K, K2, px1, px2) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    theirs = _opencv(H, K)
    r1 = cv2.undistortPoints(px1.reshape(-1, 1, 2), K, None).astype(np.float32)
    r2 = cv2.undistortPoints(px2.reshape(-1, 1, 2), K2, None).astype(np.float32)
    Rs = [c[0] for c in theirs]
    ns = [c[2].reshape(3, 1) for c in theirs]
    idx = cv2.filterHomographyDecompByVisibleRefpoints(Rs, ns, r1, r2)
    return [] if idx is None else [theirs[i] for i in idx.ravel()]


def test_visibility_keeps_truth_and_matches_opencv_filter():
    rng = np.random.default_rng(3)
    counts = []
    for _ in range(200):
        K = _random_K(rng)
        R, t, n, px1, px2 = _visible_config(rng, K, K)
        H = _homography(R, t, n, K, scale=rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 2.0))
        sols = decompose_homography(H, K, points=px1, points2=px2)
        counts.append(len(sols))
        assert 1 <= len(sols) <= 2  # at most one of each (R, t, n), (R, -t, -n) pair is visible
        assert min(_dist(s, R, t, n) for s in sols) < EXACT
        m1 = np.column_stack([px1, np.ones(len(px1))]) @ np.linalg.inv(K).T
        m2 = np.column_stack([px2, np.ones(len(px2))]) @ np.linalg.inv(K).T
        for s in sols:
            assert np.all(m1 @ s.n > 0) and np.all(m2 @ (s.R @ s.n) > 0)
        # Points transferred by H instead of measured: the same selection.
        same = decompose_homography(H, K, points=px1)
        assert len(same) == len(sols)
        # OpenCV's selection (its filter runs on float32 rectified points): same candidates.
        theirs = _opencv_selection(H, K, K, px1, px2)
        assert len(theirs) == len(sols)
        for s in sols:
            assert min(_dist(s, *c) for c in theirs) < VS_OPENCV
    # "Typically two remain" (spec 01 §3): most configurations keep both physical solutions.
    assert np.mean(np.array(counts) == 2) > 0.5


def test_points_behind_a_camera_leave_no_candidate():
    rng = np.random.default_rng(5)
    K = _random_K(rng)
    R, t, n, px1, _ = _visible_config(rng, K, K)
    # Turn camera 2 round (180 deg about its y axis): same plane, same side, but every point is
    # now behind it. The homography is still a valid one; no candidate passes visibility.
    F = np.diag([-1.0, 1.0, -1.0])
    R2, t2 = F @ R, F @ t
    H = _homography(R2, t2, n, K)
    x2h = np.column_stack([px1, np.ones(len(px1))]) @ H.T
    px2_behind = x2h[:, :2] / x2h[:, 2:]
    assert min(_dist(s, R2, t2, n) for s in decompose_homography(H, K)) < EXACT
    assert decompose_homography(H, K, points=px1, points2=px2_behind) == []
    assert decompose_homography(H, K, points=px1) == []
    assert _opencv_selection(H, K, K, px1, px2_behind) == []


def test_known_normal_gives_the_single_exact_solution():
    rng = np.random.default_rng(13)
    worst = 0.0
    for R, t, n, K, H in _random_homographies(rng, 500):
        sols = decompose_homography(H, K, normal=n * rng.uniform(0.5, 2.0))
        assert len(sols) == 1 and sols[0].case == "known_normal"
        worst = max(worst, _dist(sols[0], R, t, n))
    assert worst < EXACT


def test_known_normal_is_a_least_squares_fit_not_a_candidate_pick():
    rng = np.random.default_rng(17)
    K = _random_K(rng)
    R, t, n = _broad_config(rng)
    # Noise of 1e-3 on H_e (about what 0.5 px on 20 points gives at f = 800).
    He = R + np.outer(t, n) + rng.normal(size=(3, 3)) * 1e-3
    Hn = He / np.linalg.svd(He, compute_uv=False)[1]
    Hn = Hn * np.sign(np.linalg.det(Hn))
    (ours,) = decompose_homography(K @ Hn @ np.linalg.inv(K), K, normal=n)
    assert np.allclose(ours.n, n, atol=1e-15)

    def residual(Rc: np.ndarray) -> float:
        # ||lambda H_e - R - t n^T|| minimised over t and lambda for a given R.
        P = np.eye(3) - np.outer(n, n)
        M = Hn @ P
        lam = np.trace(Rc.T @ M) / np.sum(M * M)
        return float(np.linalg.norm(lam * M - Rc @ P))

    # The fitted rotation beats the rotation of every candidate (and small perturbations of it).
    r_ours = residual(ours.R)
    for c in decompose_homography(K @ Hn @ np.linalg.inv(K), K):
        assert r_ours <= residual(c.R) + 1e-15
    for _ in range(20):
        assert r_ours <= residual(rotvec_to_matrix(rng.normal(size=3) * 1e-4) @ ours.R)
    # And it stays close to the truth at this noise level.
    assert np.abs(ours.R - R).max() < 1e-2
    assert np.abs(ours.t - t).max() < 1e-2


def test_pure_rotation():
    rng = np.random.default_rng(19)
    K = _random_K(rng)
    R = rotvec_to_matrix([0.1, -0.3, 0.2])
    for scale in (2.5, -0.7):
        sols = decompose_homography(K @ R @ np.linalg.inv(K) * scale, K)
        assert len(sols) == 1
        (s,) = sols
        assert s.case == "pure_rotation"
        assert np.abs(s.R - R).max() < 1e-12
        assert np.all(s.t == 0) and np.array_equal(s.n, [0.0, 0.0, 1.0])
    # OpenCV also returns one candidate (its R is H_e itself, which has det -1 when H is given
    # with a negative scale, hence the positive scale here) with n = 0.
    ((Rc, tc, nc),) = _opencv(K @ R @ np.linalg.inv(K), K)
    assert np.abs(Rc - R).max() < VS_OPENCV and not tc.any() and not nc.any()
    # A translation below the threshold max |H_e^T H_e - I| < 1e-3 counts as pure rotation (as
    # in OpenCV); with the threshold at 0 it is decomposed and the truth is recovered.
    n = _unit(np.array([0.1, 0.2, 1.0]))
    t = np.array([1e-4, -2e-4, 1e-4])
    H = _homography(R, t, n, K)
    assert [s.case for s in decompose_homography(H, K)] == ["pure_rotation"]
    assert len(_opencv(H, K)) == 1
    sols = decompose_homography(H, K, rotation_tol=0.0)
    assert len(sols) == 4
    # n is conditioned by 1/|t|: ~1e-12 rounding in H_e becomes ~1e-8 in n for |t| ~ 2e-4.
    assert min(_dist(s, R, t, n) for s in sols) < 1e-7
    # Points in front of both cameras keep the pure rotation (OpenCV's n = 0 would fail).
    px = rng.uniform(0, 400, size=(10, 2))
    assert len(decompose_homography(K @ R @ np.linalg.inv(K), K, points=px)) == 1


@pytest.mark.parametrize("a", [0.4, -0.3])
def test_translation_along_the_normal(a: float):
    rng = np.random.default_rng(23)
    K = _random_K(rng)
    R = rotvec_to_matrix([0.2, 0.1, -0.1])
    n = _unit(np.array([0.2, -0.1, 1.0]))
    t = a * R @ n  # camera 2's centre -R^T t lies on the normal through camera 1
    H = _homography(R, t, n, K, scale=-1.5)
    sols = decompose_homography(H, K)
    # a > 0: s1 > s2 = s3; a < 0: s1 = s2 > s3. Either way one solution up to the sign pair.
    assert len(sols) == 2 and all(s.case == "translation_along_normal" for s in sols)
    assert min(_dist(s, R, t, n) for s in sols) < EXACT
    assert np.allclose(sols[0].t, -sols[1].t) and np.allclose(sols[0].n, -sols[1].n)
    # With points on the plane, exactly the truth remains.
    px = np.array([[300.0, 200.0], [350.0, 260.0], [280.0, 250.0], [320, 230]])
    (only,) = decompose_homography(H, K, points=px)
    assert _dist(only, R, t, n) < EXACT
    # OpenCV returns the same solution twice, or NaN when a minor rounds below zero; where it
    # is finite it agrees to sqrt(eps) ~ 1e-8 (square roots of minors that are zero in exact
    # arithmetic), hence 1e-6.
    for c in _opencv(H, K):
        if np.all(np.isfinite(c[2])):
            assert min(_dist(s, *c) for s in sols) < 1e-6


def test_batch_equals_single():
    rng = np.random.default_rng(29)
    K = _random_K(rng)
    Hs = []
    for _ in range(300):
        R, t, n = _broad_config(rng)
        Hs.append(_homography(R, t, n, K, scale=rng.choice([-1.0, 1.0])))
    R = rotvec_to_matrix([0.2, 0.1, -0.1])
    n = _unit(np.array([0.2, -0.1, 1.0]))
    Hs.append(_homography(R, np.zeros(3), n, K))  # pure rotation
    Hs.append(_homography(R, 0.3 * R @ n, n, K))  # along the normal
    Hs.append(K @ np.diag([1.0, 1.0, 0.0]) @ np.linalg.inv(K))  # singular
    res = decompose_homography_batch(np.array(Hs), K)
    assert (
        res.R.shape == (303, 4, 3, 3) and res.t.shape == (303, 4, 3) and res.n.shape == (303, 4, 3)
    )
    assert res.valid.shape == (303, 4) and res.case.shape == (303,)
    assert np.all(res.case[:300] == CASE_GENERAL)
    assert list(res.case[300:]) == [CASE_PURE_ROTATION, CASE_ALONG_NORMAL, CASE_SINGULAR]
    assert list(res.valid.sum(axis=1)[300:]) == [1, 2, 0]
    for b, H in enumerate(Hs[:302]):
        single = decompose_homography(H, K)
        keep = np.nonzero(res.valid[b])[0]
        assert len(keep) == len(single)
        for k, s in zip(keep, single, strict=True):
            assert _dist(s, res.R[b, k], res.t[b, k], res.n[b, k]) < 1e-12
    # Per-item intrinsics broadcast like a shared K.
    res2 = decompose_homography_batch(np.array(Hs[:10]), np.broadcast_to(K, (10, 3, 3)))
    assert np.allclose(res2.R, res.R[:10], atol=1e-12, equal_nan=True)


def test_typed_errors():
    K = np.diag([800.0, 800.0, 1.0])
    H = np.eye(3)
    with pytest.raises(InvalidInput):
        decompose_homography(np.eye(3, 4), K)
    with pytest.raises(InvalidInput):
        decompose_homography(np.full((3, 3), np.nan), K)
    with pytest.raises(InvalidInput):
        decompose_homography(H, K[:2])
    with pytest.raises(DegenerateConfiguration, match="K is singular"):
        decompose_homography(H, np.diag([800.0, 800.0, 0.0]))
    with pytest.raises(DegenerateConfiguration, match="K2 is singular"):
        decompose_homography(H, K, K2=np.zeros((3, 3)))
    with pytest.raises(DegenerateConfiguration, match="singular"):
        decompose_homography(np.diag([1.0, 1.0, 0.0]), K)
    with pytest.raises(DegenerateConfiguration):
        decompose_homography(np.zeros((3, 3)), K)
    with pytest.raises(InvalidInput):
        decompose_homography(H, K, points=np.zeros((4, 3)))
    with pytest.raises(InvalidInput):
        decompose_homography(H, K, points2=np.zeros((4, 2)))
    with pytest.raises(InvalidInput):
        decompose_homography(H, K, points=np.zeros((4, 2)), points2=np.zeros((5, 2)))
    with pytest.raises(InvalidInput):
        decompose_homography(H, K, normal=np.zeros(3))
    with pytest.raises(InvalidInput):
        decompose_homography(H, K, normal=[0.0, np.nan, 1.0])
    with pytest.raises(InvalidInput):
        decompose_homography(H, K, rotation_tol=-1.0)
    with pytest.raises(InvalidInput):
        decompose_homography_batch(H, K)  # not batched
    with pytest.raises(InvalidInput):
        decompose_homography_batch(np.stack([H, H]), np.stack([K, K, K]))
    with pytest.raises(DegenerateConfiguration):
        decompose_homography_batch(np.stack([H, H]), np.zeros((3, 3)))
