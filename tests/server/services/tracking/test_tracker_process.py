"""The core trackers in a process of their own (server.services.tracking.process.TrackerHost).

On a shared database the service runs its core trackers in a child process, so that their
arithmetic does not hold the API process's interpreter lock. These tests check that the child
computes what the tracker would in the service's own process (same frames, same tracks,
numbers equal to rounding), that the tracker's typed errors come
back as themselves, and that a service whose trackers' process dies starts another and goes on
with the same tracks.
"""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest

from core.errors import InvalidInput
from core.localization import NetworkCamera
from core.localization.tracking import LIVE_STATES, Tracker, TrackerConfig
from server.services.tracking import DetectionIn, TrackingService
from server.services.tracking.process import RemoteTracker, TrackerHost
from tests.support.cameras import register_cameras

K = [[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]]
DIST = [-0.1, 0.01, 0.0005, -0.0003, 0.0]
HEIGHT = 1.0
SIGMA_PX = 0.5
RATE_HZ = 10.0


def _cameras() -> list[NetworkCamera]:
    """Four ceiling cameras at the corners of a 4 m x 3 m room, looking at its middle."""
    corners = ([0.0, 0.0, 2.8], [4.0, 0.0, 2.8], [4.0, 3.0, 2.8], [0.0, 3.0, 2.8])
    return [NetworkCamera.looking_at(K, DIST, c, (2.0, 1.5, 0.0), (640, 480)) for c in corners]


def _walkers(t: float) -> np.ndarray:
    """Three people walking circles about the room's middle: (3, 3) x, y, height."""
    radius = np.array([0.5, 0.9, 1.2])
    a = np.array([0.0, 2.1, 4.2]) + np.array([0.6, -0.45, 0.3]) * t
    return np.column_stack(
        [2.0 + radius * np.cos(a), 1.5 + 0.8 * radius * np.sin(a), np.full(3, HEIGHT)]
    )


def _frames(cameras, t0: float, seconds: float, seed: int):
    """Yield (camera index, t, pixels (D, 2)) of every camera at RATE_HZ with its own phase,
    0.5 px noise and 5 % missed detections, in time order."""
    rng = np.random.default_rng(seed)
    period = 1.0 / RATE_HZ
    times = sorted(
        (t0 + period * (n + (k + 0.5) / len(cameras)), k)
        for k in range(len(cameras))
        for n in range(int(seconds * RATE_HZ))
    )
    for t, k in times:
        X = _walkers(t - t0)
        seen = cameras[k].in_view(X) & (rng.random(3) > 0.05)
        px = cameras[k].project(X[seen]) + rng.normal(0.0, SIGMA_PX, (int(seen.sum()), 2))
        yield k, t, px


def _same_snapshots(a, b) -> None:
    """The same tracks in the same states; their numbers equal to 1e-9 (m, m/s and their
    squares): the child's cameras are unpickled copies, whose derived matrices are computed
    again, which moves the last bits of the results (1.5e-14 m measured); 1e-9 is far above
    that rounding and far below any difference a transport fault would make."""
    assert [(s.id, s.state, s.kind, s.label, s.hits) for s in a] == [
        (s.id, s.state, s.kind, s.label, s.hits) for s in b
    ]
    for sa, sb in zip(a, b, strict=True):
        assert sa.t == sb.t and sa.first_seen == sb.first_seen and sa.last_seen == sb.last_seen
        np.testing.assert_allclose(sb.x, sa.x, rtol=0.0, atol=1e-9)
        np.testing.assert_allclose(sb.cov, sa.cov, rtol=0.0, atol=1e-9)


def test_the_trackers_process_answers_as_the_tracker_itself():
    cameras = _cameras()
    config = TrackerConfig()
    here = Tracker(config=config, next_id=7)
    host = TrackerHost()
    try:
        there = RemoteTracker(host, config, 7, None)
        for k, cam in enumerate(cameras):
            here.set_camera(k, cam)
            there.set_camera(k, cam)
        cov = np.tile(np.eye(2) * SIGMA_PX**2, (3, 1, 1))
        births = 0
        for k, t, px in _frames(cameras, 1000.0, 6.0, seed=4):
            args = (k, t, px, cov[: len(px)])
            kwargs = {"heights": np.full(len(px), HEIGHT), "kinds": ["person"] * len(px)}
            a, b = here.update(*args, **kwargs), there.update(*args, **kwargs)
            _same_snapshots(a.updated, b.updated)
            _same_snapshots(a.ended, b.ended)
            assert (there.time, len(there)) == (here.time, len(here))
            births = max(births, len(here))
        # Three walkers in view of four cameras: three tracks, confirmed.
        live = here.tracks(states=LIVE_STATES)
        assert len(live) == 3 and births == 3
        _same_snapshots(live, there.tracks(states=LIVE_STATES))
        _same_snapshots(here.tracks(1006.5), there.tracks(1006.5))
        here.shift(2.0)
        there.shift(2.0)
        _same_snapshots(here.advance(1008.5), there.advance(1008.5))
        assert there.time == here.time == 1008.5
        # A restore on a fresh tracker (a takeover) keeps the ids on both sides.
        fresh_here = Tracker(config=config, next_id=20)
        fresh_there = RemoteTracker(host, config, 20, None)
        t = max(s.t for s in live) + 0.1
        _same_snapshots(fresh_here.restore(t, live), fresh_there.restore(t, live))
        _same_snapshots(fresh_here.tracks(), fresh_there.tracks())
        assert {s.id for s in fresh_there.tracks()} == {s.id for s in live}
        # The tracker's typed errors come back as themselves, with their message.
        with pytest.raises(InvalidInput, match="back in time"):
            there.shift(-1.0)
        fresh_there.close()
    finally:
        host.close()
    assert not host.process.is_alive()


class _Clock:
    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_a_service_whose_trackers_process_dies_goes_on_with_its_tracks(client, admin):
    cameras = _cameras()
    ids = register_cameras(client, admin, cameras)
    factory = client.app.state.runtime.session_factory
    live = client.app.state.runtime.targets
    t0 = float(np.ceil(time.time())) + 1.0
    clock = _Clock(t0)
    service = TrackingService(factory, live, latency=0.2, clock=clock, separate_process=True)
    space_of = dict.fromkeys(ids, None)
    cov = ((SIGMA_PX**2, 0.0), (0.0, SIGMA_PX**2))

    def feed(frames) -> None:
        """Ingest one second of frames, 0.1 s at a time, the clock following them."""
        batch: list[DetectionIn] = []
        for k, t, px in frames:
            batch += [
                DetectionIn(ids[k], t, (float(u), float(v)), cov, "person", HEIGHT) for u, v in px
            ]
            if len(batch) >= 12:
                with factory() as session:
                    service.ingest(session, batch, space_of)
                batch = []
                clock.t = t + service.latency
                service.process(clock.t)

    frames = list(_frames(cameras, t0, 6.0, seed=9))
    half = len(frames) // 2
    try:
        feed(frames[:half])
        before = {s.id for s in service.tracks(None)}
        assert len(before) == 3
        live.flush()  # what a new trackers' process restores from
        host = service._host
        assert host is not None and host.process.pid != os.getpid()
        os.kill(host.process.pid, signal.SIGKILL)
        host.process.join(5)
        with pytest.raises(Exception, match="trackers' process"):
            service.process(clock.t)
        service._recover()
        assert service._host is not None and service._host.process.pid != host.process.pid
        assert {s.id for s in service.tracks(None)} == before
        feed(frames[half:])
        after = service.tracks(None)
        # The same three people, followed on under the same ids, where they are now (0.5 px
        # at ~3 m is ~3 mm; 0.15 m allows the filter's lag and the restored tracks' speed).
        assert {s.id for s in after} == before
        truth = _walkers(frames[-1][1] - t0)[:, :2]
        for s in after:
            assert np.min(np.linalg.norm(truth - s.x[:2], axis=1)) < 0.15, s
    finally:
        service.stop()
