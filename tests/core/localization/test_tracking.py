"""Floor tracker: filter consistency, association without swaps, gating, track life, cameras."""

from __future__ import annotations

import numpy as np
import pytest
from localization_scene import ROOM, make_cameras
from scipy.integrate import quad_vec
from scipy.stats import chi2

from core.errors import InvalidInput
from core.localization.tracking import (
    FloorTracker,
    TrackerConfig,
    TrackStatus,
    cv_process_noise,
    cv_transition,
)

# 2-dof chi-square quantile at 99.73 %, the two-dimensional counterpart of "within 3 sigma".
CHI2_2DOF_3SIGMA = chi2.ppf(0.9973, 2)
CHI2_4DOF_3SIGMA = chi2.ppf(0.9973, 4)


def _cv_truth(rng, n_steps, q, dt_range=(0.05, 0.15)):
    """Return times (K,) and states (K, 4) of a target following the CV model with noise q."""
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(*dt_range, n_steps - 1))])
    s = np.empty((n_steps, 4))
    s[0] = [rng.uniform(2, 6), rng.uniform(2, 4), *rng.normal(0.0, 0.5, 2)]
    for k in range(1, n_steps):
        dt = t[k] - t[k - 1]
        w = rng.multivariate_normal(np.zeros(4), cv_process_noise(dt, q))
        s[k] = cv_transition(dt) @ s[k - 1] + w
    return t, s


def test_process_noise_is_the_integral_of_white_acceleration():
    # Independent reference: Q = int_0^dt F(s) G q G^T F(s)^T ds by adaptive quadrature.
    q, dt = 0.7, 0.37
    G = np.zeros((4, 2))
    G[2:] = np.eye(2)
    Q = quad_vec(lambda s: cv_transition(s) @ G @ (q * G.T) @ cv_transition(s).T, 0.0, dt)[0]
    assert np.allclose(cv_process_noise(dt, q), Q, rtol=1e-10, atol=1e-15)


def test_single_target_nees_is_consistent_and_filters_the_noise():
    rng = np.random.default_rng(3)
    q = 0.1
    R = np.array([[0.05**2, 0.3 * 0.05 * 0.03], [0.3 * 0.05 * 0.03, 0.03**2]])
    L = np.linalg.cholesky(R)
    n_runs, n_steps, skip = 100, 60, 10
    nees = np.empty((n_runs, n_steps - skip))
    err_f, err_z, reported = [], [], []
    for r in range(n_runs):
        t, s = _cv_truth(rng, n_steps, q)
        z = s[:, :2] + rng.standard_normal((n_steps, 2)) @ L.T
        # The truth's initial speed is drawn with std 0.5 m/s, which the prior must cover. The
        # gates are opened wide: gating drops the 1 % largest innovations, which would bias the
        # NEES of the plain Kalman filter under test low.
        cfg = TrackerConfig(q=q, initial_speed_std=0.5, gate=1e4, birth_gate=2e4)
        trk = FloorTracker(cfg)
        for k in range(n_steps):
            trk.update(t[k], z[k : k + 1], R)
            (tr,) = trk.tracks()
            if k >= skip:
                e = tr.state - s[k]
                nees[r, k - skip] = e @ np.linalg.solve(tr.cov, e)
                err_f.append(tr.xy - s[k, :2])
                reported.append(np.trace(tr.xy_cov))
                err_z.append(z[k] - s[k, :2])
    # Final-step NEES of independent runs: sum ~ chi2(4 n_runs), so the mean has std
    # sqrt(8 / n_runs) = 0.28; +-3.3 std (99.9 %) is [3.07, 4.93].
    final = nees[:, -1].mean()
    assert 3.07 < final < 4.93, final
    # Time-and-run average: correlated in time, so a looser band than chi2(4 N) would give;
    # a filter with Q or R off by a factor of two lands outside [3.5, 4.5].
    assert 3.5 < nees.mean() < 4.5, nees.mean()
    rmse_f = np.sqrt(np.mean(np.sum(np.square(err_f), axis=1)))
    rmse_z = np.sqrt(np.mean(np.sum(np.square(err_z), axis=1)))
    # With q dt^3 << R the filter averages several measurements: well below the raw error
    # (0.70 of it here), and as large as the filter's own covariance says (Monte Carlo
    # error of an RMSE over 5000 correlated samples: a few percent).
    assert rmse_f < 0.8 * rmse_z, (rmse_f, rmse_z)
    assert abs(rmse_f / np.sqrt(np.mean(reported)) - 1.0) < 0.1


def test_two_crossing_targets_keep_their_ids():
    rng = np.random.default_rng(7)
    sigma = 0.03
    # Two targets at 1 m/s on crossing paths, 0.8 m apart at their closest (t = 2 s).
    p0 = np.array([[2.0, 2.6], [6.0, 3.4]])
    v = np.array([[1.0, 0.0], [-1.0, 0.0]])
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(0.05, 0.12, 60))])
    trk = FloorTracker(TrackerConfig(q=0.1))
    owner: dict[int, set[int]] = {0: set(), 1: set()}
    for tk in t:
        truth = p0 + v * tk
        z = truth + rng.normal(0.0, sigma, truth.shape)
        order = rng.permutation(2)  # no help from the measurement order
        res = trk.update(tk, z[order], np.eye(2) * sigma**2)
        for j, target in enumerate(order):
            if res.track_ids[j] >= 0:  # -1: outside the 99 % gate, dropped
                owner[int(target)].add(int(res.track_ids[j]))
    assert np.min(np.linalg.norm(np.diff(p0 + v * t[:, None, None], axis=1), axis=2)) < 0.81
    # Each target fed exactly one track, never the other's.
    assert len(owner[0]) == 1 and len(owner[1]) == 1 and owner[0] != owner[1]
    tracks = trk.tracks(confirmed_only=True)
    assert len(tracks) == 2
    for tr in tracks:
        target = 0 if tr.id in owner[0] else 1
        e = tr.state - np.concatenate([p0[target] + v[target] * t[-1], v[target]])
        assert e @ np.linalg.solve(tr.cov, e) < CHI2_4DOF_3SIGMA  # position and velocity


def test_clutter_is_gated_out_and_never_confirmed():
    rng = np.random.default_rng(5)
    sigma = 0.03
    cfg = TrackerConfig(q=0.1, confirm_hits=4, confirm_window=5, max_miss_time=0.5)
    trk = FloorTracker(cfg)
    target_id = None
    dropped = 0
    for k in range(100):
        tk = 0.1 * k
        truth = np.array([1.0 + 0.5 * tk, 3.0])
        z_target = truth + rng.normal(0.0, sigma, 2)
        # Three false detections a frame, one of them within 0.45 m of the target, all at least
        # 0.15 m (5 sigma) from it: nearer, no gate could tell them from the target.
        clutter = rng.uniform([0, 0], ROOM, size=(3, 2))
        clutter[0] = truth + rng.uniform(-0.3, 0.3, 2)
        clutter[0] += 0.15 * np.sign(clutter[0] - truth)
        while np.any(np.linalg.norm(clutter - truth, axis=1) < 0.15):
            near = np.linalg.norm(clutter - truth, axis=1) < 0.15
            clutter[near] = rng.uniform([0, 0], ROOM, size=(int(near.sum()), 2))
        z = np.vstack([z_target, clutter])
        res = trk.update(tk, z, np.eye(2) * sigma**2)
        if target_id is None:
            target_id = int(res.track_ids[0])
        # The target's own detection may fall outside the 99 % gate (then it is dropped).
        assert res.track_ids[0] in (target_id, -1)
        dropped += int(res.track_ids[0] == -1)
        assert target_id not in res.track_ids[1:].tolist()
    assert dropped <= 4  # binomial(100, 0.01): P(> 4) = 0.3 %
    confirmed = trk.tracks(confirmed_only=True)
    assert [tr.id for tr in confirmed] == [target_id]
    e = confirmed[0].xy - truth
    assert e @ np.linalg.solve(confirmed[0].xy_cov, e) < CHI2_2DOF_3SIGMA


def test_birth_confirmation_and_deletion():
    cfg = TrackerConfig(q=0.1, confirm_hits=3, confirm_window=4, max_miss_time=0.35)
    trk = FloorTracker(cfg)
    R = np.eye(2) * 0.02**2
    res = trk.update(0.0, [[1.0, 1.0]], R)
    assert res.started.tolist() == [True]
    tid = int(res.track_ids[0])
    (tr,) = trk.tracks()
    assert tr.status is TrackStatus.TENTATIVE and tr.hits == 1
    trk.update(0.1, [[1.0, 1.0]], R)
    assert trk.tracks()[0].status is TrackStatus.TENTATIVE
    trk.update(0.2, [[1.0, 1.0]], R)
    (tr,) = trk.tracks()
    assert tr.status is TrackStatus.CONFIRMED and tr.id == tid and tr.hits == 3
    assert [p.t for p in tr.history] == [0.0, 0.1, 0.2]
    # Missed at 0.3, 0.5: alive while the gap is <= 0.35 s, deleted when it exceeds it.
    assert trk.update(0.5, np.zeros((0, 2)), R).deleted == ()
    assert trk.update(0.6, np.zeros((0, 2)), R).deleted == (tid,)
    assert len(trk) == 0
    # A tentative track that misses its window is deleted after N = 4 frames.
    res = trk.update(1.0, [[5.0, 5.0]], R)
    lone = int(res.track_ids[0])
    trk.update(1.05, np.zeros((0, 2)), R)
    trk.update(1.1, np.zeros((0, 2)), R)
    assert trk.update(1.15, np.zeros((0, 2)), R).deleted == (lone,)
    # New ids are never reused.
    assert int(trk.update(1.2, [[5.0, 5.0]], R).track_ids[0]) > lone


def test_labelled_measurements_go_to_their_track():
    trk = FloorTracker(TrackerConfig(q=0.1))
    R = np.eye(2) * 0.02**2
    res = trk.update(0.0, [[1.0, 1.0], [1.2, 1.0]], R, labels=["robot", None])
    robot, person = res.track_ids.tolist()
    # Swapped positions: the labelled one still goes to the robot's track, ungated.
    res = trk.update(0.1, [[1.0, 1.0], [1.2, 1.0]], R, labels=[None, "robot"])
    assert res.track_ids.tolist() == [person, robot]
    labels = {tr.id: tr.label for tr in trk.tracks()}
    assert labels == {robot: "robot", person: None}
    # A detection of the robot without its label may still update the robot's track (no
    # duplicate), but a labelled one never goes to another track, however close.
    at = {tr.id: tr.xy for tr in trk.tracks(t=0.2)}
    res = trk.update(0.2, [at[robot]], R)
    assert res.track_ids.tolist() == [robot]
    at = {tr.id: tr.xy for tr in trk.tracks(t=0.3)}
    res = trk.update(0.3, [at[person]], R, labels=["cart"])
    assert res.started.tolist() == [True] and res.track_ids[0] not in (robot, person)


def test_prediction_follows_constant_velocity():
    trk = FloorTracker(TrackerConfig(q=0.01, confirm_hits=1))
    R = np.eye(2) * 1e-6
    for k in range(5):
        trk.update(0.5 * k, [[1.0 + 0.2 * 0.5 * k, 2.0 - 0.1 * 0.5 * k]], R)
    (now,) = trk.tracks()
    (later,) = trk.tracks(t=3.0)
    assert np.allclose(later.xy, now.xy + 1.0 * now.velocity)
    assert np.allclose(now.velocity, [0.2, -0.1], atol=1e-3)
    assert np.all(np.linalg.eigvalsh(later.xy_cov) > np.linalg.eigvalsh(now.xy_cov))
    assert trk.tracks()[0].t == 2.0  # asking for a prediction stores nothing


@pytest.fixture(scope="module")
def cams3():
    return make_cameras(3)


def test_cross_camera_tracking_of_ten_targets(cams3):
    rng = np.random.default_rng(21)
    sigma = 0.5
    h = 0.0
    gx, gy = np.meshgrid(np.linspace(1.6, 6.4, 5), np.linspace(2.0, 4.0, 2))
    p0 = np.column_stack([gx.ravel(), gy.ravel()]) + rng.uniform(-0.2, 0.2, (10, 2))
    angle = rng.uniform(0, 2 * np.pi, 10)
    v = 0.3 * np.column_stack([np.cos(angle), np.sin(angle)])
    trk = FloorTracker(TrackerConfig(q=0.05, height=h), cameras=cams3)
    n_frames, dt = 50, 0.1
    owner = [set() for _ in range(10)]
    d2_all = []
    n_det = n_dropped = 0
    for f in range(n_frames):
        tk = f * dt
        truth = p0 + v * tk
        P = np.column_stack([truth, np.full(10, h)])
        cam_idx, pixels, target = [], [], []
        for k, cam in enumerate(cams3):
            seen = np.flatnonzero(cam.in_view(P))
            cam_idx += [k] * seen.size
            pixels.append(cam.project(P[seen]) + rng.normal(0.0, sigma, (seen.size, 2)))
            target += seen.tolist()
        order = rng.permutation(len(cam_idx))
        res = trk.update_detections(
            tk,
            np.asarray(cam_idx)[order],
            np.vstack(pixels)[order],
            pixel_sigma=sigma,
        )
        tgt = np.asarray(target)[order]
        n_det += tgt.size
        n_dropped += int(np.sum(res.track_ids < 0))
        for j in range(10):
            owner[j] |= set(res.track_ids[(tgt == j) & (res.track_ids >= 0)].tolist())
        if f >= 5:
            by_id = {tr.id: tr for tr in trk.tracks(confirmed_only=True)}
            for j in range(10):
                (tid,) = owner[j]
                e = by_id[tid].xy - truth[j]
                d2_all.append(e @ np.linalg.solve(by_id[tid].xy_cov, e))
    # The 99 % gate drops 1 % of true detections (a single camera's outliers); no more.
    assert n_dropped <= 0.02 * n_det, (n_dropped, n_det)
    # One track per target, all different, all confirmed: no swaps, no duplicates.
    assert all(len(o) == 1 for o in owner)
    assert len(set.union(*owner)) == 10
    assert len(trk.tracks(confirmed_only=True)) == 10 and len(trk) == 10
    # Within 3 sigma: 0.27 % of the 450 checks may exceed the 99.73 % quantile by chance
    # (expected 1.2), so allow 1 %; none may be beyond the 1e-6 quantile (27.6).
    d2_all = np.asarray(d2_all)
    assert np.mean(d2_all > CHI2_2DOF_3SIGMA) <= 0.01, np.sort(d2_all)[-5:]
    assert d2_all.max() < chi2.ppf(1.0 - 1e-6, 2)


def test_bad_input_raises_invalid_input(cams3):
    trk = FloorTracker(TrackerConfig(q=0.1))
    R = np.eye(2) * 1e-4
    with pytest.raises(InvalidInput):
        trk.update(0.0, [[1.0, np.nan]], R)
    with pytest.raises(InvalidInput):
        trk.update(0.0, [[1.0, 2.0, 3.0]], R)
    with pytest.raises(InvalidInput):
        trk.update(0.0, [[1.0, 2.0]], np.diag([1e-4, -1e-4]))
    with pytest.raises(InvalidInput):
        trk.update(0.0, [[1.0, 2.0]], R, labels=["a", "b"])
    trk.update(1.0, [[1.0, 2.0]], R)
    with pytest.raises(InvalidInput, match="backwards"):
        trk.update(0.5, [[1.0, 2.0]], R)
    with pytest.raises(InvalidInput, match="cameras"):
        trk.update_detections(2.0, [0], [[1.0, 2.0]])
    cam_trk = FloorTracker(cameras=cams3)
    with pytest.raises(InvalidInput):
        cam_trk.update_detections(0.0, [3], [[100.0, 200.0]])
    with pytest.raises(InvalidInput):
        cam_trk.update_detections(0.0, [0.5], [[100.0, 200.0]])
    with pytest.raises(InvalidInput):
        cam_trk.update_detections(0.0, [0], [[100.0, 200.0]], pixel_sigma=0.0)
    with pytest.raises(InvalidInput):
        TrackerConfig(q=-1.0)
    with pytest.raises(InvalidInput):
        TrackerConfig(confirm_hits=4, confirm_window=3)
    with pytest.raises(InvalidInput):
        FloorTracker(config=object())  # type: ignore[arg-type]


def test_cross_camera_labels_and_clutter(cams3):
    rng = np.random.default_rng(8)
    sigma = 0.5
    p0 = np.array([[2.0, 2.0], [4.0, 3.5], [6.0, 2.5], [3.0, 4.5]])
    v = np.array([[0.3, 0.1], [-0.2, -0.2], [0.0, 0.3], [0.25, -0.1]])
    labels_of = ["robot", None, None, None]
    cfg = TrackerConfig(q=0.05, confirm_hits=4, confirm_window=5, max_miss_time=0.3)
    trk = FloorTracker(cfg, cameras=cams3)
    owner: list[set[int]] = [set() for _ in range(4)]
    clutter_tracks = 0
    for f in range(40):
        tk = 0.1 * f
        P = np.column_stack([p0 + v * tk, np.zeros(4)])
        cam_idx, pixels, target = [], [], []
        for k, cam in enumerate(cams3):
            seen = np.flatnonzero(cam.in_view(P))
            cam_idx += [k] * (seen.size + 2)
            pixels.append(cam.project(P[seen]) + rng.normal(0.0, sigma, (seen.size, 2)))
            # Two false detections a camera and frame, anywhere in the image.
            pixels.append(rng.uniform([0, 0], [1279, 799], (2, 2)))
            target += [*seen.tolist(), -1, -1]
        tgt = np.asarray(target)
        labels = [labels_of[j] if j >= 0 else None for j in tgt]
        res = trk.update_detections(
            tk, np.asarray(cam_idx), np.vstack(pixels), pixel_sigma=sigma, labels=labels
        )
        for j in range(4):
            owner[j] |= set(res.track_ids[(tgt == j) & (res.track_ids >= 0)].tolist())
        true_ids = set().union(*owner)
        assert not true_ids & set(res.track_ids[tgt < 0].tolist())
        clutter_tracks += int(np.sum(res.started[tgt < 0]))
    assert clutter_tracks > 100  # the clutter did start tentative tracks; none survived
    assert all(len(o) == 1 for o in owner) and len(set().union(*owner)) == 4
    confirmed = {tr.id: tr for tr in trk.tracks(confirmed_only=True)}
    assert set(confirmed) == set().union(*owner)
    assert confirmed[next(iter(owner[0]))].label == "robot"
    assert all(confirmed[next(iter(owner[j]))].label is None for j in (1, 2, 3))
