"""Calibration runs: queued in the database, claimed and executed off the event loop (a thread
pool in the API process, or `intspace worker` processes), finished or marked interrupted."""

from __future__ import annotations

import logging
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from sqlalchemy import select, update
from sqlalchemy.orm import Session, sessionmaker

from core.errors import IntspaceError
from server.db.base import utcnow
from server.db.models import (
    RUN_FAILED,
    RUN_INTERRUPTED,
    RUN_QUEUED,
    RUN_RUNNING,
    RUN_SUCCEEDED,
    CalibrationRun,
    CalibrationRunFile,
)
from server.services import calibration

log = logging.getLogger(__name__)


def interrupt_unfinished_runs(factory: sessionmaker[Session], reason: str) -> int:
    """Mark every queued or running run as interrupted; return how many were."""
    with factory() as session:
        result = session.execute(
            update(CalibrationRun)
            .where(CalibrationRun.status.in_((RUN_QUEUED, RUN_RUNNING)))
            .values(status=RUN_INTERRUPTED, error=reason, finished_at=utcnow())
        )
        session.commit()
        return int(result.rowcount or 0)


def claim_run(session: Session, run_id: int) -> bool:
    """Move run `run_id` from queued to running; return False when someone else has it (or it
    was interrupted). The conditional UPDATE is atomic on SQLite and PostgreSQL alike."""
    result = session.execute(
        update(CalibrationRun)
        .where(CalibrationRun.id == run_id, CalibrationRun.status == RUN_QUEUED)
        .values(status=RUN_RUNNING, started_at=utcnow())
    )
    session.commit()
    return result.rowcount == 1


def claim_next_run(session: Session) -> int | None:
    """Claim the oldest queued run; return its id, None when the queue is empty. On PostgreSQL
    the row is locked with SKIP LOCKED, so concurrent workers never wait on each other."""
    stmt = (
        select(CalibrationRun.id)
        .where(CalibrationRun.status == RUN_QUEUED)
        .order_by(CalibrationRun.id)
        .limit(1)
    )
    if session.get_bind().dialect.name == "postgresql":
        stmt = stmt.with_for_update(skip_locked=True)
    run_id = session.scalar(stmt)
    if run_id is None:
        session.rollback()
        return None
    return run_id if claim_run(session, run_id) else None


def _finish(session: Session, run_id: int, **values: Any) -> None:
    # Only a run still marked running is finished: one interrupted meanwhile stays interrupted.
    session.execute(
        update(CalibrationRun)
        .where(CalibrationRun.id == run_id, CalibrationRun.status == RUN_RUNNING)
        .values(finished_at=utcnow(), **values)
    )
    session.commit()


def compute(session: Session, run: CalibrationRun) -> dict[str, Any]:
    """Return the result of a claimed run (raising core's typed errors on bad data)."""
    if run.kind == "network":
        return calibration.calibrate_network(run.inputs, run.options)
    if run.source == "images":
        files = session.scalars(
            select(CalibrationRunFile.data)
            .where(CalibrationRunFile.run_id == run.id)
            .order_by(CalibrationRunFile.position)
        ).all()
        return calibration.calibrate_from_images(list(files), run.inputs, run.options)
    return calibration.calibrate_from_correspondences(run.inputs, run.options)


def execute_claimed_run(factory: sessionmaker[Session], run_id: int) -> str:
    """Execute a run already claimed (status running); return its final status."""
    with factory() as session:
        run = session.get(CalibrationRun, run_id)
        if run is None:
            return RUN_FAILED
        try:
            result = compute(session, run)
        except IntspaceError as exc:
            _finish(session, run_id, status=RUN_FAILED, error=f"{type(exc).__name__}: {exc}")
            return RUN_FAILED
        except Exception as exc:
            log.exception("calibration run %s crashed", run_id)
            _finish(session, run_id, status=RUN_FAILED, error=f"internal error: {exc!r}")
            return RUN_FAILED
        _finish(session, run_id, status=RUN_SUCCEEDED, result=result, error=None)
        return RUN_SUCCEEDED


def execute_run(factory: sessionmaker[Session], run_id: int) -> str | None:
    """Claim and execute run `run_id`; return its final status, None if it was not claimable."""
    with factory() as session:
        if not claim_run(session, run_id):
            return None
    return execute_claimed_run(factory, run_id)


class RunExecutor:
    """Executes the runs this API process queues, in a thread pool (numpy and OpenCV release the
    GIL in their heavy parts, and a thread can be abandoned at shutdown, unlike a process's
    pickled state)."""

    def __init__(self, factory: sessionmaker[Session], workers: int) -> None:
        self._factory = factory
        self._pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="calibration")
        self._lock = threading.Lock()
        self._closed = False

    def submit(self, run_id: int) -> None:
        """Queue run `run_id` (already committed as queued) for execution."""
        with self._lock:
            if self._closed:
                return
            self._pool.submit(self._run, run_id)

    def _run(self, run_id: int) -> None:
        try:
            execute_run(self._factory, run_id)
        except Exception:  # the pool would swallow it silently
            log.exception("calibration run %s could not be executed", run_id)

    def shutdown(self) -> int:
        """Stop taking runs, drop those not started and mark every unfinished run interrupted
        (a run still computing keeps that mark when it ends); return how many were marked."""
        with self._lock:
            self._closed = True
        self._pool.shutdown(wait=False, cancel_futures=True)
        return interrupt_unfinished_runs(self._factory, "interrupted by service shutdown")


def interrupt_run(factory: sessionmaker[Session], run_id: int, reason: str) -> None:
    """Mark one run interrupted if it has not finished."""
    with factory() as session:
        session.execute(
            update(CalibrationRun)
            .where(
                CalibrationRun.id == run_id, CalibrationRun.status.in_((RUN_QUEUED, RUN_RUNNING))
            )
            .values(status=RUN_INTERRUPTED, error=reason, finished_at=utcnow())
        )
        session.commit()
