"""The one job engine (server.services.jobs) on the kinds without a queue: a path's follow task
whose service died is given up as interrupted, its old holder can write nothing, and another
service starts it again; a robot task waiting for a worker keeps its lease past the lease's
length and is interrupted when its runner stops. Calibration runs, the kind with a queue, are
tests/server/services/test_worker_leases.py's."""

from __future__ import annotations

import time
from datetime import timedelta

import pytest
from sqlalchemy import update

from server.db.base import utcnow
from server.db.models import PlannedPath, Space, Task
from server.db.session import make_engine, make_session_factory
from server.services.jobs import JobCancelled, Lease, LeasePolicy, lease_expired, release_expired
from server.services.manipulation import TaskRunner
from server.services.path_following import FOLLOW_LEASES, FOLLOWS, claim_follow


@pytest.fixture
def factory(database_url):
    engine = make_engine(database_url, pool_size=2)
    yield make_session_factory(engine)
    engine.dispose()


def _path(factory) -> int:
    with factory() as session:
        space = Space(name="home")
        session.add(space)
        session.flush()
        row = PlannedPath(
            space_id=space.id,
            start=[0.0, 0.0],
            goal=[1.0, 0.0],
            points=[[0.0, 0.0], [1.0, 0.0]],
            length_m=1.0,
            robot_radius_m=0.2,
            resolution_m=0.05,
            floor_plan="registered rooms",
            follow_status="idle",
        )
        session.add(row)
        session.commit()
        return row.id


def test_a_follow_whose_service_died_is_interrupted_then_started_again(factory):
    path_id = _path(factory)
    with factory() as session:
        assert claim_follow(session, path_id, "a", FOLLOW_LEASES, "adaptive", 1)
        # While "a" holds it, nobody else starts it.
        assert not claim_follow(session, path_id, "b", FOLLOW_LEASES, "adaptive", 2)
        assert release_expired(session, FOLLOWS, FOLLOW_LEASES).total == 0
    Lease(factory, FOLLOWS, path_id, "a").write(follow_progress=0.5)
    # "a" died: its lease runs out, and the next look gives the task up with the reason.
    with factory() as session:
        session.execute(
            update(PlannedPath)
            .where(PlannedPath.id == path_id)
            .values(lease_expires_at=utcnow() - timedelta(seconds=1))
        )
        session.commit()
        released = release_expired(session, FOLLOWS, FOLLOW_LEASES)
        assert (released.requeued, released.given_up) == (0, 1)
        row = session.get(PlannedPath, path_id)
        assert row is not None
        assert (row.follow_status, row.follow_progress, row.lease_owner) == (
            "interrupted",
            0.5,
            None,
        )
        assert row.follow_error is not None and "stopped" in row.follow_error
        assert row.follow_finished_at is not None
    # What "a" would still write is refused; "b" starts the path again, afresh.
    stale = Lease(factory, FOLLOWS, path_id, "a")
    with pytest.raises(JobCancelled):
        stale.write(follow_progress=0.9)
    with factory() as session:
        assert not stale.finish(session, follow_status="succeeded")
        assert claim_follow(session, path_id, "b", FOLLOW_LEASES, "proportional", 3)
        row = session.get(PlannedPath, path_id)
        assert row is not None
        assert (row.follow_status, row.follow_law, row.follow_seed) == (
            "running",
            "proportional",
            3,
        )
        assert (row.follow_progress, row.follow_error, row.follow_finished_at) == (0.0, None, None)
        assert (row.lease_owner, row.attempts) == ("b", 2)


def test_a_task_waiting_for_a_worker_keeps_its_lease_until_its_runner_stops(factory):
    policy = LeasePolicy(lease_s=2.0, heartbeat_s=0.25, max_attempts=1)
    runner = TaskRunner(factory, workers=0, policy=policy)  # no worker: the task stays queued
    other = TaskRunner(factory, workers=0, policy=policy)  # another process's runner
    try:
        with factory() as session:
            task = Task(kind="fetch", status="queued", inputs={}, **runner.lease())
            session.add(task)
            session.commit()
            task_id = task.id
        runner.submit(task_id)
        # Two and a half leases later it is still held: the heartbeat renewed its lease (time
        # must pass: a lease not renewed would have expired by then).
        time.sleep(2.5 * policy.lease_s)
        with factory() as session:
            assert other.settle(session).total == 0
            row = session.get(Task, task_id)
            assert row is not None and not lease_expired(row)
            assert (row.status, row.lease_owner, row.attempts) == ("queued", runner.owner, 1)
    finally:
        released = runner.shutdown()
        other.shutdown()
    assert released == 1
    with factory() as session:
        row = session.get(Task, task_id)
        assert row is not None
        assert (row.status, row.error, row.lease_owner) == (
            "interrupted",
            "the service stopped during it",
            None,
        )
        assert row.finished_at is not None
