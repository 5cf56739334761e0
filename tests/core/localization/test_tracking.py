"""The asynchronous EKF tracker: filter consistency from unsynchronised cameras, the life cycle
by elapsed time, clutter that never becomes a target, crossing targets, bad input, the
reorder buffer."""

from __future__ import annotations

import numpy as np
import pytest
from localization_scene import ROOM, make_cameras
from scipy.integrate import quad_vec
from scipy.stats import chi2

from core.errors import InvalidInput
from core.localization.occluders import Occluders, Wall
from core.localization.reorder import ReorderBuffer
from core.localization.tracking import (
    CONFIRM_GAPS,
    Tracker,
    TrackerConfig,
    TrackState,
    cv_process_noise,
    cv_transition,
)

HEIGHT = 1.0


def _cv_truth(rng, t, q, start):
    """Return states (K, 4) of a target following the CV model with noise q at times t (K,)."""
    s = np.empty((t.size, 4))
    s[0] = start
    for k in range(1, t.size):
        dt = t[k] - t[k - 1]
        w = np.linalg.cholesky(cv_process_noise(dt, q)) @ rng.standard_normal(4) if dt > 0 else 0
        s[k] = cv_transition(dt) @ s[k - 1] + w
    return s


def _async_times(rng, n_cam, duration, rate=10.0):
    """Return (times, camera index) of n_cam cameras at `rate` Hz with their own phases."""
    t, c = [], []
    for k in range(n_cam):
        tk = rng.uniform(0, 1 / rate) + np.arange(0.0, duration, 1 / rate)
        t.append(tk)
        c.append(np.full(tk.size, k))
    t, c = np.concatenate(t), np.concatenate(c)
    order = np.argsort(t, kind="stable")
    return t[order], c[order]


def test_process_noise_is_the_integral_of_white_acceleration():
    # Independent reference: Q = int_0^dt F(s) G q G^T F(s)^T ds by adaptive quadrature.
    q, dt = 0.7, 0.37
    G = np.zeros((4, 2))
    G[2:] = np.eye(2)
    Q = quad_vec(lambda s: cv_transition(s) @ G @ (q * G.T) @ cv_transition(s).T, 0.0, dt)[0]
    assert np.allclose(cv_process_noise(dt, q), Q, rtol=1e-10, atol=1e-15)


def test_unsynchronised_cameras_give_a_consistent_filter():
    """NEES of the 4-D state from four cameras at 10 Hz with their own phases: the filter's
    covariance agrees with its errors, and fusing beats one camera's back-projection."""
    rng = np.random.default_rng(11)
    cams = make_cameras(4)
    q, sigma = 0.2, 0.7
    # The cameras here are exact: no calibration error to allow for.
    cfg = TrackerConfig(q=q, initial_speed_std=0.5, gate=1e4, confirm_hits=1, camera_error_std=0.0)
    n_runs, duration, skip = 8, 6.0, 2.0
    nees, errors, reported = [], [], []
    for _ in range(n_runs):
        t, cam = _async_times(rng, 4, duration)
        start = [rng.uniform(3, 5), rng.uniform(2.5, 3.5), *rng.normal(0, 0.3, 2)]
        s = _cv_truth(rng, t, q, start)
        trk = Tracker(cams, cfg)
        for k in range(t.size):
            X = np.array([[s[k, 0], s[k, 1], HEIGHT]])
            if not cams[cam[k]].in_view(X)[0]:
                trk.advance(t[k])
                continue
            u = cams[cam[k]].project(X) + rng.normal(0, sigma, (1, 2))
            trk.update(int(cam[k]), t[k], u, pixel_sigma=sigma, heights=HEIGHT)
            if t[k] >= skip and len(trk) == 1:
                tr = trk.tracks()[0]
                e = tr.x - s[k]
                nees.append(e @ np.linalg.solve(tr.cov, e))
                errors.append(e[:2] @ e[:2])
                reported.append(np.trace(tr.xy_cov))
    nees = np.asarray(nees)
    # Consecutive NEES values are correlated, so the mean's spread is wider than chi2/N; over
    # 8 independent runs a 15 % band around the expected 4 is still several standard errors
    # (the per-run means have a spread of about 0.25 at these rates).
    assert nees.size > 1000
    assert abs(nees.mean() - 4.0) < 0.6, nees.mean()
    assert np.mean(nees > chi2.ppf(0.99, 4)) < 0.03
    # The position errors agree with the covariance the filter reports (same 15 % band).
    ratio = np.sqrt(np.mean(errors) / np.mean(reported))
    assert 0.85 < ratio < 1.15, ratio


def test_life_cycle_by_elapsed_time():
    cams = make_cameras(4)
    cfg = TrackerConfig(confirm_hits=3, coast_after=0.5, end_after=2.0)
    trk = Tracker(cams, cfg)
    X = np.array([[4.0, 3.0, HEIGHT]])
    t = 0.0
    states = []
    for k in range(12):  # four cameras, 3 rounds at 10 Hz each: ~0.3 s of frames
        t = 0.025 * k
        r = trk.update(k % 4, t, cams[k % 4].project(X), pixel_sigma=0.5, heights=HEIGHT)
        states.append(r.updated[0].state)
    assert states[0] is TrackState.TENTATIVE
    assert states[-1] is TrackState.CONFIRMED
    (tr,) = trk.tracks()
    tid, first = tr.id, tr.first_seen
    assert tr.first_seen == 0.0 and tr.last_seen == pytest.approx(t)
    # Silence: coasting after coast_after, ended after end_after, reported once.
    assert trk.advance(t + 0.4) == ()
    assert trk.tracks()[0].state is TrackState.CONFIRMED
    assert trk.advance(t + 0.6) == ()
    assert trk.tracks()[0].state is TrackState.COASTING
    ended = trk.advance(t + 2.1)
    assert [e.id for e in ended] == [tid] and ended[0].state is TrackState.ENDED
    assert ended[0].first_seen == first and ended[0].last_seen == pytest.approx(t)
    assert len(trk) == 0 and trk.advance(t + 3.0) == ()
    # The same body again is a new track: ids are never reused.
    r = trk.update(0, t + 3.1, cams[0].project(X), pixel_sigma=0.5, heights=HEIGHT)
    assert r.started[0] and r.track_ids[0] > tid


def test_a_coasting_track_is_taken_up_again():
    cams = make_cameras(4)
    trk = Tracker(cams, TrackerConfig(coast_after=0.3, end_after=3.0))
    X = np.array([[4.0, 3.0, HEIGHT]])
    for k in range(20):
        trk.update(k % 4, 0.025 * k, cams[k % 4].project(X), pixel_sigma=0.5, heights=HEIGHT)
    tid = trk.tracks()[0].id
    trk.advance(1.5)
    assert trk.tracks()[0].state is TrackState.COASTING
    r = trk.update(1, 1.55, cams[1].project(X), pixel_sigma=0.5, heights=HEIGHT)
    assert r.track_ids[0] == tid and r.updated[0].state is TrackState.CONFIRMED


def test_a_detection_that_cannot_place_a_body_is_left_out():
    """A blob of two people one behind the other places its body a metre off with a wide
    covariance: it neither starts a track nor moves one, and its track id is -1."""
    cams = make_cameras(4)
    cfg = TrackerConfig()
    trk = Tracker(cams, cfg)
    X = np.array([[4.0, 3.0, HEIGHT]])
    for k in range(20):
        trk.update(k % 4, 0.025 * k, cams[k % 4].project(X), pixel_sigma=0.5, heights=HEIGHT)
    (before,) = trk.tracks()
    # A pixel 1 m off, with a covariance that spreads it over metres of floor (the floor
    # Jacobian here is 56-160 px/m, so 150 px is 0.9-2.7 m: over located_std).
    far = cams[1].project(X + np.array([1.0, 0.0, 0.0]))
    r = trk.update(1, 0.5, far, np.eye(2) * 150.0**2, heights=HEIGHT)
    assert r.track_ids.tolist() == [-1] and not r.started[0] and r.updated == ()
    (after,) = trk.tracks()
    assert after.id == before.id and after.last_seen == before.last_seen
    # Nothing pulled the track: it is where its own prediction puts it.
    assert np.linalg.norm(after.xy - X[0, :2]) < 0.05
    # Alone, such detections never start a track; with located_std = 0 they do.
    lone = Tracker(cams, cfg)
    assert lone.update(1, 0.0, far, np.eye(2) * 150.0**2, heights=HEIGHT).track_ids[0] == -1
    every = Tracker(cams, TrackerConfig(located_std=0.0))
    assert every.update(1, 0.0, far, np.eye(2) * 150.0**2, heights=HEIGHT).started[0]


def _hidden_b(hiding: bool, vague_instead: bool = False) -> list[tuple[float, TrackState]]:
    """Body B (4, 3) seen by cam2 alone at 10 Hz for a second; cam0 (20 Hz, 1.2 s) has B in view but
    reports only body A (2, 1.5), confirmed before, which stands between cam0 and B (`hiding`),
    or, without A, nothing, or one vague blob where B is (`vague_instead`). Return the tracks'
    (x, state) at the end."""
    cams = make_cameras(4)
    A, B = np.array([[2.0, 1.5, HEIGHT]]), np.array([[4.0, 3.0, HEIGHT]])
    trk = Tracker(cams, TrackerConfig())
    t = 0.0
    if hiding:
        for k in range(12):
            t, c = 0.05 * k, (0, 3)[k % 2]
            trk.update(c, t, cams[c].project(A), pixel_sigma=0.5, heights=HEIGHT)
    frames = sorted(
        [(t + 0.05 + 0.1 * i, 2) for i in range(10)] + [(t + 0.06 + 0.05 * i, 0) for i in range(20)]
    )
    for tt, c in frames:
        if c == 2:
            seen = np.vstack([B, A]) if hiding else B
            trk.update(2, tt, cams[2].project(seen), pixel_sigma=0.5, heights=HEIGHT)
        elif hiding:
            trk.update(0, tt, cams[0].project(A), pixel_sigma=0.5, heights=HEIGHT)
        elif vague_instead:
            # Placed by its width alone: 150 px spreads it over metres of floor.
            trk.update(0, tt, cams[0].project(B), np.eye(2) * 150.0**2, heights=HEIGHT)
        else:
            trk.update(0, tt, np.zeros((0, 2)), heights=HEIGHT)
    return [(round(float(s.xy[0]), 1), s.state) for s in trk.tracks()]


def test_a_body_hidden_behind_another_is_not_missed():
    """cam0 cannot see B behind A: its frames are no evidence against B, which one other camera
    confirms within a second. The same frames with nobody in front of B are misses, and B (seen
    by one camera in two) is dropped as clutter would be; a blob left out as too vague where B
    stands is no miss either."""
    assert _hidden_b(hiding=True) == [
        (2.0, TrackState.CONFIRMED),
        (4.0, TrackState.CONFIRMED),
    ]
    assert TrackState.CONFIRMED not in [state for _, state in _hidden_b(hiding=False)]
    assert _hidden_b(hiding=False, vague_instead=True) == [(4.0, TrackState.CONFIRMED)]


def test_a_camera_does_not_see_through_walls():
    """A track coasting behind a wall (its position now uncertain by 0.8 m) does not take the
    detection of a camera on the other side, 1.8 m away: a new track starts there and the old
    one stays put. Without the occluders the old track is pulled through the wall."""
    cams = make_cameras(4)
    wall = Occluders.build(walls=[Wall((4.0, -1.0), (4.0, 7.0), height=3.0)])
    left, right = np.array([[3.0, 3.0, HEIGHT]]), np.array([[4.8, 3.0, HEIGHT]])
    for occluders in (wall, None):
        trk = Tracker(cams, TrackerConfig(), occluders=occluders)
        for k in range(12):  # cam0 and cam3 are on the wall's left
            c = (0, 3)[k % 2]
            trk.update(c, 0.05 * k, cams[c].project(left), pixel_sigma=0.5, heights=HEIGHT)
        (before,) = trk.tracks()
        trk.advance(1.5)
        r = trk.update(1, 1.5, cams[1].project(right), pixel_sigma=0.5, heights=HEIGHT)
        old = next(s for s in trk.tracks() if s.id == before.id)
        if occluders is not None:
            assert r.started[0] and r.track_ids[0] != before.id
            np.testing.assert_allclose(old.xy, left[0, :2], atol=0.02)
        else:
            assert r.track_ids[0] == before.id and old.xy[0] > 4.0


def test_a_camera_reporting_slowly_still_confirms_a_body():
    """One camera detecting twice a second (a node on a slow machine): the default timeout
    (0.4 s) and window (1 s) alone would drop the tentative track between any two frames. They
    stretch to the camera's frame interval, so the body is confirmed from its sightings' score
    as at 10 Hz; clutter at that rate still never is."""
    cams = make_cameras(1)
    rng = np.random.default_rng(2)
    cfg = TrackerConfig()
    needed = {}
    for rate in (10.0, 2.0):
        trk = Tracker(cams, cfg)
        states = []
        for k in range(12):
            t = k / rate
            X = np.array([[3.0 + 0.5 * t, 3.0, HEIGHT]])  # walking at 0.5 m/s
            px = cams[0].project(X) + rng.normal(0.0, 0.5, (1, 2))
            r = trk.update(0, t, px, pixel_sigma=0.5, heights=HEIGHT)
            states.append(r.updated[0].state if r.updated else None)
        assert TrackState.CONFIRMED in states, (rate, states)
        needed[rate] = states.index(TrackState.CONFIRMED) + 1
        assert all(st is TrackState.CONFIRMED for st in states[needed[rate] :]), (rate, states)
    # Its score (the log-likelihood ratio of its sightings) confirms it: at 2 Hz each
    # prediction is vaguer, so each sighting weighs less and more are needed, within the
    # window's stretch (CONFIRM_GAPS intervals).
    assert cfg.confirm_hits <= needed[10.0] <= needed[2.0] <= CONFIRM_GAPS
    # A camera silent for a minute (its node restarted) is not a slow camera: its new tentative
    # track still times out after the default 0.4 s.
    trk = Tracker(cams, cfg)
    X = np.array([[3.0, 3.0, HEIGHT]])
    for t in (0.0, 0.1):
        trk.update(0, t, cams[0].project(X), pixel_sigma=0.5, heights=HEIGHT)
    trk.advance(60.0)
    r = trk.update(0, 60.1, cams[0].project(X), pixel_sigma=0.5, heights=HEIGHT)
    assert r.started[0] and len(trk) == 1
    assert trk.advance(60.1 + 0.5) == () and len(trk) == 0
    # Clutter at 2 Hz, two false detections per frame over the image, for a minute.
    trk = Tracker(cams, cfg)
    w, h = cams[0].image_size
    confirmed = set()
    for k in range(120):
        n = rng.poisson(2.0)
        px = np.column_stack([rng.uniform(0, w, n), rng.uniform(0, h, n)])
        r = trk.update(0, k * 0.5, px, pixel_sigma=0.7, heights=HEIGHT)
        confirmed |= {s.id for s in r.updated if s.state is not TrackState.TENTATIVE}
    assert confirmed == set()


def test_clutter_alone_never_becomes_a_target():
    """Half a minute of four cameras at 10 Hz with two false detections per frame uniform over
    the image: tracks are born from clutter but none is confirmed."""
    rng = np.random.default_rng(5)
    cams = make_cameras(4)
    trk = Tracker(cams)
    w, h = cams[0].image_size
    t, cam = _async_times(rng, 4, 30.0)
    confirmed = set()
    for k in range(t.size):
        n = rng.poisson(2.0)
        px = np.column_stack([rng.uniform(0, w, n), rng.uniform(0, h, n)])
        r = trk.update(int(cam[k]), t[k], px, pixel_sigma=0.7, heights=HEIGHT)
        confirmed |= {s.id for s in r.updated if s.state is not TrackState.TENTATIVE}
    assert confirmed == set()


def test_two_people_crossing_keep_their_ids():
    """Two walkers cross at right angles at one point at the same time, seen by four
    unsynchronised cameras with 0.7 px noise: each track stays on its walker throughout."""
    rng = np.random.default_rng(8)
    cams = make_cameras(4)
    trk = Tracker(cams)
    t, cam = _async_times(rng, 4, 8.0)
    centre = np.array([ROOM[0] / 2, ROOM[1] / 2])
    a = centre + np.outer(t - 4.0, [0.9, 0.0])
    b = centre + np.outer(t - 4.0, [0.0, 0.9])
    errors: dict[int, list[tuple[float, float]]] = {}
    for k in range(t.size):
        X = np.column_stack([np.stack([a[k], b[k]]), [HEIGHT, HEIGHT]])
        px = cams[cam[k]].project(X) + rng.normal(0, 0.7, (2, 2))
        r = trk.update(int(cam[k]), t[k], px, pixel_sigma=0.7, heights=HEIGHT, kinds="person")
        for snap in r.updated:
            if snap.state is TrackState.CONFIRMED:
                d = (np.linalg.norm(snap.xy - a[k]), np.linalg.norm(snap.xy - b[k]))
                errors.setdefault(snap.id, []).append(d)
    confirmed = [s for s in trk.tracks() if s.state is TrackState.CONFIRMED]
    assert len(confirmed) == 2 and set(errors) == {s.id for s in confirmed}
    walker_of = {}
    for tid, d in errors.items():
        d = np.array(d)
        own = int(np.argmin(d[0]))  # the walker the track was born on
        walker_of[tid] = own
        # Never nearer the other walker by more than the noise, before, at and after the
        # crossing (at the crossing both walkers are at one point).
        assert np.all(d[:, own] <= d[:, 1 - own] + 0.02), tid
        assert np.max(d[:, own]) < 0.1
    assert sorted(walker_of.values()) == [0, 1]


def test_kinds_and_labels_steer_association():
    cams = make_cameras(4)
    trk = Tracker(cams, TrackerConfig(confirm_hits=1))
    robot = np.array([[4.0, 3.0, 0.36]])
    person = np.array([[4.3, 3.0, HEIGHT]])
    r = trk.update(0, 0.0, cams[0].project(robot), heights=0.36, kinds="robot", labels="robot")
    rid = int(r.track_ids[0])
    assert trk.tracks()[0].label == "robot" and trk.tracks()[0].kind == "robot"
    # A person detection next to the robot is not the robot (kinds differ) and, being within
    # min_separation, starts no new body either.
    r = trk.update(1, 0.05, cams[1].project(person), heights=HEIGHT, kinds="person")
    assert r.track_ids[0] == -1 and len(trk) == 1
    # The labelled robot detection goes to the robot's track even far from its prediction.
    far = np.array([[5.0, 3.5, 0.36]])
    r = trk.update(2, 0.1, cams[2].project(far), heights=0.36, kinds="robot", labels="robot")
    assert r.track_ids[0] == rid


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"pixels": [[1.0, 2.0, 3.0]]}, "shape"),
        ({"pixels": [[np.nan, 2.0]]}, "NaN"),
        ({"pixels": [[1.0, 2.0]], "heights": [1.0, 2.0]}, "heights"),
        ({"pixels": [[1.0, 2.0]], "kinds": ["cat"]}, "kinds"),
        ({"pixels": [[1.0, 2.0]], "pixel_cov": [[1.0, 2.0], [2.0, 1.0]]}, "positive definite"),
        ({"pixels": [[1.0, 2.0], [3.0, 4.0]], "labels": ["a", "a"]}, "label twice"),
        ({"pixels": [[1.0, 2.0]], "appearances": [[0.5], [0.5]]}, "one row per pixel"),
        ({"pixels": [[1.0, 2.0]], "appearances": [[-0.5, 0.5]]}, "non-negative"),
    ],
)
def test_bad_frames_are_refused_by_name(kwargs, message):
    trk = Tracker(make_cameras(2))
    with pytest.raises(InvalidInput, match=message):
        trk.update(0, 0.0, **kwargs)


def test_unknown_camera_time_backwards_and_bad_settings_are_refused():
    trk = Tracker(make_cameras(2))
    with pytest.raises(InvalidInput, match="unknown camera"):
        trk.update(5, 0.0, np.zeros((0, 2)))
    trk.update(0, 10.0, np.zeros((0, 2)))
    with pytest.raises(InvalidInput, match="backwards"):
        trk.update(1, 9.0, np.zeros((0, 2)))
    with pytest.raises(InvalidInput, match="q"):
        TrackerConfig(q=-1.0)
    with pytest.raises(InvalidInput, match="end_after"):
        TrackerConfig(coast_after=2.0, end_after=1.0)
    with pytest.raises(InvalidInput, match="p_detect"):
        TrackerConfig(p_detect=1.0)
    with pytest.raises(InvalidInput, match="appearance_weight"):
        TrackerConfig(appearance_weight=-1.0)
    with pytest.raises(InvalidInput, match="recognition_distance"):
        TrackerConfig(recognition_distance=1.5)
    with pytest.raises(InvalidInput, match="appearance_rate"):
        TrackerConfig(appearance_rate=0.0)


def test_reorder_buffer_releases_in_time_order_and_counts_late_frames():
    buf = ReorderBuffer(latency=0.1, limit=100)
    for t in (1.00, 1.03, 0.98, 1.05):
        assert buf.push(t, f"f{t}")
    assert buf.pop_ready(1.09) == [(0.98, "f0.98")]
    assert [t for t, _ in buf.pop_ready(1.2)] == [1.00, 1.03, 1.05]
    # The window is closed up to 1.2 - 0.1: older frames are late, newer ones still queue.
    assert not buf.push(1.04, "late") and not buf.push(1.09, "late") and buf.late == 2
    assert buf.push(1.11, "in time") and buf.pop_ready(2.0) == [(1.11, "in time")]
    small = ReorderBuffer(latency=10.0, limit=2)
    for t in (1.0, 2.0, 3.0):
        small.push(t, t)
    assert small.pop_ready(0.0) == [(1.0, 1.0)] and len(small) == 2


def test_reorder_buffer_releases_at_the_watermark_of_the_cameras_it_hears():
    buf = ReorderBuffer(latency=1.0)
    # Two cameras, each delivering 0.2 s after capture; camera b is a frame behind camera a.
    assert buf.push(10.0, "a10", source="a", arrived=10.2)
    assert buf.push(10.1, "a10.1", source="a", arrived=10.3)
    assert buf.push(10.05, "b10.05", source="b", arrived=10.3)
    # Both have delivered up to 10.05: that much is released 0.95 s before the window's end.
    assert buf.pop_ready(10.3) == [(10.0, "a10"), (10.05, "b10.05")]
    assert buf.pop_ready(10.35) == []  # b has not yet delivered anything after 10.05
    assert buf.push(10.15, "b10.15", source="b", arrived=10.4)
    assert buf.pop_ready(10.4) == [(10.1, "a10.1")]
    # Camera a falls silent: after the window b alone sets the watermark, and a frame of a's
    # older than what was released is late.
    assert buf.push(12.0, "b12", source="b", arrived=12.2)
    assert [t for t, _ in buf.pop_ready(12.2)] == [10.15, 12.0]
    assert not buf.push(11.0, "a11", source="a", arrived=12.3) and buf.late == 1
    # A source's clock ahead of `now` never releases beyond `now`.
    ahead = ReorderBuffer(latency=1.0)
    assert ahead.push(5.0, "c5", source="c", arrived=3.0)
    assert ahead.pop_ready(3.0) == [] and ahead.released == 3.0


def _disagreeing_cameras_track(config: TrackerConfig) -> tuple[np.ndarray, float, list[int]]:
    """A still robot seen by two cameras whose calibrations disagree by 3 cm on the floor
    (the second one's pose shifted), frames 5 ms apart, each pixel sure to 0.05 px: return the
    track's last state, its largest speed and how many of each camera's detections updated a
    track."""
    cams = make_cameras(2)
    T = cams[1].T_world_camera.copy()
    T[:3, 3] += [0.03, 0.0, 0.0]  # what camera 1 believes: 3 cm off
    believed = [
        cams[0],
        type(cams[1]).from_pose(cams[1].K, cams[1].dist, T, cams[1].image_size, "cam1"),
    ]
    tracker = Tracker(believed, config)
    point = np.array([[2.0, 2.0, HEIGHT]])
    speed = 0.0
    used = [0, 0]
    first = None
    for k in range(400):
        cam = k % 2
        t = 0.1 * (k // 2) + 0.005 * cam
        px = cams[cam].project(point)  # the true camera makes the pixel
        r = tracker.update(cam, t, px, np.eye(2) * 0.05**2, heights=HEIGHT, kinds="robot")
        ids = [u.id for u in r.updated]
        first = first if first is not None else (ids[0] if ids else None)
        used[cam] += int(first in ids)
        for s in tracker.tracks():
            if s.id == first and k > 20:
                speed = max(speed, float(np.hypot(*s.x[2:])))
    track = next(s for s in tracker.tracks() if s.id == first)
    return track.x, speed, used


def test_cameras_that_disagree_by_their_calibration_error_share_one_track():
    x, speed, used = _disagreeing_cameras_track(TrackerConfig())
    # The calibration term (2 cm on the floor) makes the two views' 3 cm disagreement an
    # expected one: both cameras update the one track, the still robot stays still and
    # between the two.
    assert min(used) >= 190, used
    assert speed < 0.2, speed
    assert np.linalg.norm(x[:2] - [2.0 + 0.015, 2.0]) < 0.01, x
    # Without it the two views cannot be the same body: one camera's detections are refused.
    _, _, alone = _disagreeing_cameras_track(TrackerConfig(camera_error_std=0.0))
    assert min(alone) < 10, alone


def test_a_person_inside_the_robot_is_the_robots_body():
    """A camera that misses the robot's marker fits its body (with its mast, or a person
    beside it) as a person: a "person" detection inside a confirmed robot track updates no
    person and starts no track; one beside the robot (0.5 m away) is a person's."""
    cams = make_cameras(2)
    trk = Tracker(cams, TrackerConfig(camera_error_std=0.0))
    robot = np.array([4.0, 3.0, 0.36])
    walker = np.array([4.5, 3.0, HEIGHT])
    t = 0.0
    for _ in range(15):  # both confirmed
        t += 0.1
        for k in (0, 1):
            at = t + 0.02 * k
            trk.update(
                k, at, cams[k].project(robot[None]), heights=0.36, kinds="robot", labels="robot"
            )
            trk.update(k, at + 0.01, cams[k].project(walker[None]), heights=HEIGHT, kinds="person")
    # The walker unseen for a second (behind someone): its track grows vague around it.
    for _ in range(10):
        t += 0.1
        for k in (0, 1):
            trk.update(
                k,
                t + 0.02 * k,
                cams[k].project(robot[None]),
                heights=0.36,
                kinds="robot",
                labels="robot",
            )
    live = {s.id: s for s in trk.tracks()}
    assert len(live) == 2
    person = next(s for s in live.values() if s.kind == "person")
    # Camera 1 misses the marker and reports the robot's body as a person at its centre.
    body = cams[1].project(np.array([[robot[0], robot[1], HEIGHT]]))
    res = trk.update(1, t + 0.05, body, heights=HEIGHT, kinds="person")
    assert res.track_ids[0] == -1 and not res.started[0]
    after = {s.id: s for s in trk.tracks()}
    assert len(after) == 2
    np.testing.assert_allclose(after[person.id].xy, person.xy, atol=0.05)
    # The walker's own detection, half a metre from the robot, still counts.
    res = trk.update(1, t + 0.06, cams[1].project(walker[None]), heights=HEIGHT, kinds="person")
    assert res.track_ids[0] == person.id
