"""Tracker.restore: a tracker that takes over another's tracks (a service process taking over a
space's tracker) keeps their ids and goes on as the original would have."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from localization_scene import make_cameras

from core.errors import InvalidInput
from core.localization.tracking import (
    Tracker,
    TrackerConfig,
    TrackSnapshot,
    TrackState,
    cv_process_noise,
    cv_transition,
)

HEIGHT = 1.0


def _frames(rng, duration, n_cam=4, rate=10.0):
    """Return (times, camera index) of n_cam cameras at `rate` Hz with their own phases."""
    t = np.concatenate(
        [rng.uniform(0, 1 / rate) + np.arange(0.0, duration, 1 / rate) for _ in range(n_cam)]
    )
    c = np.concatenate([np.full(t.size // n_cam, k) for k in range(n_cam)])
    order = np.argsort(t, kind="stable")
    return t[order], c[order]


def _walkers(t):
    """Two bodies walking apart in parallel lanes at 0.8 and 0.6 m/s (never within 1.5 m)."""
    a = np.column_stack([1.5 + 0.8 * t, np.full(t.size, 2.0)])
    b = np.column_stack([6.5 - 0.6 * t, np.full(t.size, 4.0)])
    return np.stack([a, b], axis=1)  # (K, 2, 2)


def _feed(trk, cams, t, cam, xy, rng, sigma=0.7):
    """Feed frames k of (t, cam) with the walkers' noisy pixels; return each frame's result."""
    out = []
    for k in range(t.size):
        X = np.column_stack([xy[k], [HEIGHT, HEIGHT]])
        seen = cams[cam[k]].in_view(X)
        px = cams[cam[k]].project(X[seen]) + rng.normal(0, sigma, (int(seen.sum()), 2))
        out.append(trk.update(int(cam[k]), t[k], px, pixel_sigma=sigma, heights=HEIGHT))
    return out


def test_a_restored_tracker_goes_on_as_the_original():
    """Snapshots taken mid-run and restored into a fresh tracker: fed the same later frames,
    the two trackers report the same ids and the same states (to rounding), and neither
    starts a new target."""
    rng = np.random.default_rng(21)
    cams = make_cameras(4)
    t, cam = _frames(rng, 6.0)
    xy = _walkers(t)
    noise = np.random.default_rng(5)
    original = Tracker(cams)
    half = t.size // 2
    _feed(original, cams, t[:half], cam[:half], xy[:half], noise)
    snaps = original.tracks(states=(TrackState.CONFIRMED, TrackState.COASTING))
    assert len(snaps) == 2
    restored = Tracker(cams)
    assert restored.restore(float(original.time), snaps) == ()
    assert restored.next_id == original.next_id
    state = noise.bit_generator.state
    a = _feed(original, cams, t[half:], cam[half:], xy[half:], noise)
    noise.bit_generator.state = state
    b = _feed(restored, cams, t[half:], cam[half:], xy[half:], noise)
    for ra, rb in zip(a, b, strict=True):
        assert np.array_equal(ra.track_ids, rb.track_ids)
    sa, sb = original.tracks(), restored.tracks()
    assert [s.id for s in sa] == [s.id for s in sb] == [s.id for s in snaps]
    for p, q in zip(sa, sb, strict=True):
        # The same floating-point operations on the same numbers, but for the restore's own
        # prediction of zero length: equal to 1e-9 m.
        assert np.allclose(p.x, q.x, atol=1e-9) and np.allclose(p.cov, q.cov, atol=1e-12)
        assert (p.hits, p.first_seen, p.last_seen) == (q.hits, q.first_seen, q.last_seen)
    # Against the truth: still on its walker, within 5 cm (0.7 px at 3-7 m is ~1 cm per camera).
    truth = xy[-1]
    for s in sb:
        assert np.min(np.linalg.norm(truth - s.xy, axis=1)) < 0.05


def test_snapshots_of_different_times_are_predicted_to_the_restore_time():
    """Each snapshot is moved from its own time by the constant-velocity model: the same as
    cv_transition / cv_process_noise (the model's independent definition) apply."""
    cfg = TrackerConfig(q=0.8)
    snap_a = _snapshot(1, t=10.0, x=[1.0, 2.0, 0.5, -0.2], last=10.0)
    snap_b = _snapshot(2, t=10.4, x=[5.0, 3.0, 0.0, 0.3], last=10.4)
    trk = Tracker(make_cameras(2), cfg)
    assert trk.restore(10.5, [snap_a, snap_b]) == ()
    by_id = {s.id: s for s in trk.tracks()}
    for snap in (snap_a, snap_b):
        dt = 10.5 - snap.t
        F = cv_transition(dt)
        assert np.allclose(by_id[snap.id].x, F @ snap.x, atol=1e-12)
        assert np.allclose(by_id[snap.id].cov, F @ snap.cov @ F.T + cv_process_noise(dt, 0.8))
        assert by_id[snap.id].t == 10.5
    assert trk.time == 10.5 and trk.next_id == 3


def test_a_restore_with_unknown_speed_keeps_the_walkers_ids():
    """Stored targets carry no velocity: restored with a zero speed and the prior speed
    variance, 0.3 s old, the tracks still take their walkers' next detections (no new target,
    same ids) and are back within 5 cm of the truth within a second."""
    rng = np.random.default_rng(3)
    cams = make_cameras(4)
    cfg = TrackerConfig()
    t, cam = _frames(rng, 3.0)
    t = t + 2.0  # the walkers are 2 s into their walk
    xy = _walkers(t)
    noise = np.random.default_rng(9)
    snaps = []
    for i, tid in enumerate((41, 57)):
        P = np.diag([0.03**2, 0.03**2, cfg.initial_speed_std**2, cfg.initial_speed_std**2])
        start = _walkers(np.array([1.7]))[0, i]
        x = np.array([start[0], start[1], 0.0, 0.0])
        snaps.append(_snapshot(tid, t=1.7, x=x, cov=P, last=1.7, first=0.2, hits=40))
    trk = Tracker(cams, cfg, next_id=7)
    trk.restore(float(t[0]) - 1e-3, snaps)
    results = _feed(trk, cams, t, cam, xy, noise)
    ids = {int(i) for r in results for i in r.track_ids if i >= 0}
    assert ids == {41, 57}
    assert not any(r.started.any() for r in results)
    assert trk.next_id == 58
    late = t >= t[0] + 1.0
    for k, r in enumerate(results):
        if not late[k]:
            continue
        for s in r.updated:
            lane = 0 if s.id == 41 else 1
            assert np.linalg.norm(s.xy - xy[k, lane]) < 0.05, (s.id, t[k])


def test_a_track_silent_too_long_ends_at_the_restore():
    cfg = TrackerConfig(coast_after=0.5, end_after=2.0)
    trk = Tracker(make_cameras(1), cfg)
    fresh = _snapshot(3, t=9.8, x=[4.0, 3.0, 0.0, 0.0], last=9.8)
    silent = _snapshot(4, t=9.0, x=[2.0, 3.0, 0.0, 0.0], last=9.0)
    gone = _snapshot(5, t=7.0, x=[6.0, 3.0, 0.0, 0.0], last=7.0)
    ended = trk.restore(10.0, [fresh, silent, gone])
    assert [s.id for s in ended] == [5] and ended[0].state is TrackState.ENDED
    states = {s.id: s.state for s in trk.tracks()}
    assert states == {3: TrackState.CONFIRMED, 4: TrackState.COASTING}


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"state": TrackState.TENTATIVE}, "only confirmed or coasting"),
        ({"t": 11.0}, "after the restore time"),
        ({"kind": "cat"}, "not one of"),
        ({"id": 0}, "integer >= 1"),
        ({"x": np.array([np.nan, 0.0, 0.0, 0.0])}, "finite"),
        ({"cov": -np.eye(4)}, "positive semi-definite"),
        ({"first_seen": 9.9, "last_seen": 9.0}, "first_seen <= last_seen"),
    ],
)
def test_bad_snapshots_are_refused_by_name(change, message):
    snap = dataclasses.replace(_snapshot(1, t=10.0, x=[1.0, 1.0, 0.0, 0.0], last=10.0), **change)
    with pytest.raises(InvalidInput, match=message):
        Tracker(make_cameras(1)).restore(10.0, [snap])


def test_ids_must_be_new_and_time_must_not_go_back():
    trk = Tracker(make_cameras(1))
    snap = _snapshot(2, t=5.0, x=[1.0, 1.0, 0.0, 0.0], last=5.0)
    trk.restore(5.0, [snap])
    with pytest.raises(InvalidInput, match="distinct and new"):
        trk.restore(6.0, [dataclasses.replace(snap, t=6.0)])
    with pytest.raises(InvalidInput, match="before the tracker's time"):
        trk.restore(4.0, [])
    with pytest.raises(InvalidInput, match="distinct and new"):
        Tracker(make_cameras(1)).restore(5.0, [snap, snap])


def _snapshot(tid, *, t, x, last, first=None, cov=None, hits=10):
    P = np.diag([0.01, 0.01, 0.04, 0.04]) if cov is None else np.asarray(cov, dtype=float)
    return TrackSnapshot(
        id=tid,
        kind="person",
        label=None,
        state=TrackState.CONFIRMED,
        t=t,
        x=np.asarray(x, dtype=float),
        cov=P,
        hits=hits,
        first_seen=last - 1.0 if first is None else first,
        last_seen=last,
    )
