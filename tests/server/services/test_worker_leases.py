"""Claims on calibration runs are leases: a run whose worker dies goes back to the queue, at most
`max_attempts` times, and finishes exactly once; two `intspace worker` processes on PostgreSQL,
one killed with SIGKILL in the middle of a run."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select, update

from server.app import create_app
from server.db.base import utcnow
from server.db.models import CalibrationRun
from server.db.session import make_engine, make_session_factory
from server.services.jobs import JobCancelled, LeasePolicy, claim_next, release_expired, renew
from server.services.runs import RUNS, Attempt
from tests.support.chessboard_photos import K_TRUE, POSES, SQUARE_M, chessboard_photo
from tests.support.waiting import run_progress, wait_for_run, wait_until, wait_while_advancing

REPO_ROOT = Path(__file__).resolve().parents[3]
PHOTOS = 16
BODY = {
    "kind": "intrinsics",
    "image_size": [640, 480],
    "object_points": [[[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]] * 3,
    "image_points": [[[0, 0], [10, 0], [10, 10], [0, 10]]] * 3,
}


@pytest.fixture
def factory(database_url):
    engine = make_engine(database_url, pool_size=2)
    yield make_session_factory(engine)
    engine.dispose()


def _queue_runs(make_settings, admin, count: int) -> list[int]:
    with TestClient(create_app(make_settings(run_executor="external"))) as client:
        camera = client.post(
            "/api/v1/cameras", json={"name": "c", "width": 640, "height": 480}, headers=admin
        ).json()["id"]
        return [
            client.post(
                "/api/v1/calibration-runs", json={**BODY, "camera_id": camera}, headers=admin
            ).json()["id"]
            for _ in range(count)
        ]


def _expire(factory, run_id: int) -> None:
    with factory() as session:
        session.execute(
            update(CalibrationRun)
            .where(CalibrationRun.id == run_id)
            .values(lease_expires_at=utcnow() - timedelta(seconds=1))
        )
        session.commit()


def test_expired_claims_are_requeued_then_failed_with_the_reason(make_settings, admin, factory):
    (run_id,) = _queue_runs(make_settings, admin, 1)
    policy = LeasePolicy(lease_s=60, heartbeat_s=1, max_attempts=2)
    with factory() as session:
        assert claim_next(session, RUNS, "a", policy) == run_id
        # A live lease is not released, and its holder renews it.
        assert release_expired(session, RUNS, policy).total == 0
        assert renew(session, RUNS, "a", [run_id], policy) == set()
    _expire(factory, run_id)
    with factory() as session:
        released = release_expired(session, RUNS, policy)
        assert (released.requeued, released.given_up) == (1, 0)
        assert renew(session, RUNS, "a", [run_id], policy) == {run_id}  # "a" lost it
        assert claim_next(session, RUNS, "b", policy) == run_id
    _expire(factory, run_id)
    with factory() as session:
        released = release_expired(session, RUNS, policy)
        assert (released.requeued, released.given_up) == (0, 1)
        run = session.get(CalibrationRun, run_id)
        assert run is not None and run.status == "failed" and run.attempts == 2
        assert run.error == "its worker stopped before finishing it, 2 time(s): given up"
        assert run.lease_owner is None and run.finished_at is not None
        assert claim_next(session, RUNS, "c", policy) is None


def test_an_attempt_that_lost_its_claim_writes_nothing(make_settings, admin, factory):
    (run_id,) = _queue_runs(make_settings, admin, 1)
    policy = LeasePolicy(lease_s=60, heartbeat_s=1, max_attempts=3)
    with factory() as session:
        claim_next(session, RUNS, "slow", policy)
    slow = Attempt(factory, run_id, "slow", min_interval_s=0)
    slow.progress("stage one", 0.5)
    _expire(factory, run_id)
    with factory() as session:
        release_expired(session, RUNS, policy)
        assert claim_next(session, RUNS, "other", policy) == run_id
    # The first worker wakes up: its report stops it, and its outcome is not written.
    with pytest.raises(JobCancelled):
        slow.progress("stage two", 0.9)
    assert slow.cancel.is_set()
    with factory() as session:
        assert not slow.finish(session, status="succeeded", result={"K": "stale"})
        assert Attempt(factory, run_id, "other").finish(session, status="failed", error="x")
        run = session.get(CalibrationRun, run_id)
        assert run is not None and (run.status, run.result, run.attempts) == ("failed", None, 2)


def test_heartbeats_keep_a_run_longer_than_its_lease(make_settings, admin, factory, monkeypatch):
    import time as clock

    from server.schemas.calibration import CalibrationResult
    from server.services.calibration import intrinsics
    from server.services.runs import RunExecutor

    def long_calibration(inputs, options, progress):
        # 2.5 s of work, reporting progress (and so checking the claim) as it goes.
        for k in range(50):
            progress("long", k / 50)
            clock.sleep(0.05)
        K = [[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1]]
        return CalibrationResult(K=K, dist=[], rms=0.0, per_view_rms=[], image_size=[640, 480])

    monkeypatch.setattr(intrinsics, "calibrate_from_correspondences", long_calibration)
    (run_id,) = _queue_runs(make_settings, admin, 1)
    policy = LeasePolicy(lease_s=1.0, heartbeat_s=0.2, max_attempts=3)
    finished: list[tuple[int, str | None]] = []
    executor = RunExecutor(
        factory, 1, policy, poll_s=0.1, on_finished=lambda r, s: finished.append((r, s))
    )
    try:
        wait_until(lambda: finished, what="the run to finish", stalled_after_s=20)
    finally:
        executor.shutdown()
    with factory() as session:
        run = session.get(CalibrationRun, run_id)
        assert run is not None and run.started_at is not None and run.finished_at is not None
        # It outlived its lease 2.5 times over, and was never taken from its worker.
        assert (run.finished_at - run.started_at).total_seconds() > 2 * policy.lease_s
        assert (run.status, run.attempts, run.lease_owner) == ("succeeded", 1, None)
    assert finished == [(run_id, "succeeded")]


def _worker(database_url: str, log: Path) -> subprocess.Popen:
    env = {
        **os.environ,
        "INTSPACE_DATABASE_URL": database_url,
        "INTSPACE_RUN_WORKERS": "1",
        # Seconds, not minutes, so that the test is short: the rule is the same.
        "INTSPACE_RUN_LEASE_S": "2",
        "INTSPACE_RUN_HEARTBEAT_S": "0.4",
        "INTSPACE_RUN_MAX_ATTEMPTS": "3",
    }
    with log.open("w") as out:
        return subprocess.Popen(
            [sys.executable, "-m", "server.cli", "worker", "--poll", "0.2"],
            cwd=REPO_ROOT,
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
        )


# Several worker processes share a PostgreSQL database (spec 06): this test runs on it only.
@pytest.mark.parametrize("database_url", ["postgresql"], indirect=True)
def test_a_run_survives_its_worker_killed_and_finishes_once(
    make_settings, admin, database_url, tmp_path
):
    settings = make_settings(run_executor="external")
    logs = [tmp_path / "worker0.log", tmp_path / "worker1.log"]
    # The workers start (seconds of imports) while the photos are drawn.
    workers = [_worker(database_url, log) for log in logs]
    # 16 photos of the board: ~75 ms of detection each, a run of a second or more.
    rng = np.random.default_rng(7)
    photos = []
    for i in range(PHOTOS):
        rvec, tvec = POSES[i % len(POSES)]
        rvec = (np.asarray(rvec) + rng.normal(0, 0.03, 3)).tolist()
        photos.append(("files", (f"p{i:02d}.png", chessboard_photo(rvec, tvec, i), "image/png")))
    with TestClient(create_app(settings)) as client:
        camera = client.post(
            "/api/v1/cameras", json={"name": "c", "width": 640, "height": 480}, headers=admin
        ).json()["id"]
        try:
            response = client.post(
                "/api/v1/calibration-runs/upload",
                data={"camera_id": str(camera), "square": str(SQUARE_M), "distortion": "none"},
                files=photos,
                headers=admin,
            )
            assert response.status_code == 202, response.text
            run_id = response.json()["id"]
            url = f"/api/v1/calibration-runs/{run_id}"

            run = wait_while_advancing(
                lambda: client.get(url, headers=admin).json(),
                done=lambda run: (run["progress"] or {}).get("fraction", 0) >= 0.25,
                progress=run_progress,
                stalled_after_s=60,
                what="the run (to be a quarter done)",
            )
            assert run["status"] == "running" and run["attempts"] == 1
            engine = make_engine(database_url, pool_size=1)
            with make_session_factory(engine)() as session:
                owner = session.scalar(
                    select(CalibrationRun.lease_owner).where(CalibrationRun.id == run_id)
                )
            engine.dispose()
            pid = int(owner.split(":")[1])
            victim = next(w for w in workers if w.pid == pid)
            victim.send_signal(signal.SIGKILL)
            assert victim.wait(10) == -signal.SIGKILL
            killed_at = utcnow()

            # Its progress stands still until its lease expires and the other worker takes it.
            run = wait_for_run(lambda: client.get(url, headers=admin).json(), stalled_after_s=60)
        finally:
            for worker in workers:
                if worker.poll() is None:
                    worker.send_signal(signal.SIGTERM)
            for worker in workers:
                worker.wait(20)

    assert run["status"] == "succeeded", run["error"]
    # Claimed twice: the killed worker's attempt, then the survivor's, finished after the kill.
    assert run["attempts"] == 2
    assert datetime.fromisoformat(run["finished_at"]) > killed_at
    # The survivor computed the same calibration as any run of these photos: rendered, noisy
    # corners give the focal length to 1 % (see test_upload_of_chessboard_photos_calibrates).
    K = np.array(run["result"]["K"])
    assert K[0, 0] == pytest.approx(K_TRUE[0, 0], rel=0.01)
    assert len(run["result"]["views_used"]) + len(run["result"]["skipped"]) == PHOTOS
    # Exactly once: one worker finished it, the other never did; the survivor stopped cleanly.
    texts = {w.pid: log.read_text() for w, log in zip(workers, logs, strict=True)}
    done = f"run {run_id} succeeded"
    assert sum(text.count(done) for text in texts.values()) == 1
    assert done not in texts[victim.pid]
    survivor = next(w for w in workers if w is not victim)
    assert survivor.returncode == 0
    assert texts[survivor.pid].count(f"run {run_id} claimed") == 1


def test_a_heartbeat_slower_than_the_lease_is_refused(monkeypatch, capsys):
    from server.cli import main

    monkeypatch.setenv("INTSPACE_RUN_LEASE_S", "1")
    monkeypatch.setenv("INTSPACE_RUN_HEARTBEAT_S", "5")
    assert main(["worker"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "shorter than the lease" in err[0]
