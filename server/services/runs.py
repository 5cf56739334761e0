"""Calibration runs: queued in the database, claimed under a lease and executed off the event
loop (threads of the API process, or `intspace worker` processes), finished exactly once.

A run is a job of server.services.jobs: the claiming worker holds it under a lease it renews by
heartbeat; once the lease of a worker that died has expired any worker re-queues the run, or
fails it with the reason after `max_attempts` claims. A worker that stops on purpose hands its
runs back to the queue at once (interrupted after `max_attempts` claims). Queued runs stay
queued whatever happens to the workers, and a run's result is written once. What a run
computes is its kind's (server.services.calibration.kinds)."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from sqlalchemy.orm import Session, sessionmaker

from server.db.models import (
    RUN_FAILED,
    RUN_INTERRUPTED,
    RUN_QUEUED,
    RUN_RUNNING,
    RUN_SUCCEEDED,
    CalibrationRun,
)
from server.schemas.common import stored_json
from server.services.calibration import kind_of
from server.services.jobs import (
    JobCancelled,
    JobEngine,
    JobTable,
    Lease,
    LeasePolicy,
    failure,
    given_up_after,
)

log = logging.getLogger(__name__)


RUNS = JobTable(
    model=CalibrationRun,
    status=CalibrationRun.status,
    running=RUN_RUNNING,
    held=(RUN_RUNNING,),
    expired_reason="its worker stopped before finishing it",
    expired_status=RUN_FAILED,
    queued=RUN_QUEUED,
    claimed={
        "finished_at": None,
        "progress_stage": "starting",
        "progress_fraction": 0.0,
    },
    requeued={"progress_stage": None, "progress_fraction": None},
    interrupted=RUN_INTERRUPTED,
    given_up=given_up_after,
    started="started_at",
)


class Attempt(Lease):
    """One worker's attempt at a claimed run: reports progress (stage, fraction 0-1) while its
    claim holds and raises JobCancelled at the next report once it does not. Reports are
    written at most every `min_interval_s` unless the stage changes."""

    def __init__(
        self,
        factory: sessionmaker[Session],
        run_id: int,
        owner: str,
        cancel: threading.Event | None = None,
        min_interval_s: float = 0.25,
    ) -> None:
        super().__init__(factory, RUNS, run_id, owner, cancel)
        self._min_interval_s = min_interval_s
        self._last: tuple[str, float] | None = None

    def progress(self, stage: str, fraction: float) -> None:
        """Record how far the attempt has come; raise JobCancelled when it lost its claim."""
        self.check()
        now = time.monotonic()
        if self._last is not None and self._last[0] == stage:
            if now - self._last[1] < self._min_interval_s:
                return
        self.write(progress_stage=stage[:80], progress_fraction=min(max(fraction, 0.0), 1.0))
        self._last = (stage, now)


def queue_run(
    session: Session, run: CalibrationRun, executor: RunExecutor | None
) -> CalibrationRun:
    """Store `run` queued and tell the in-process executor (None: external workers poll the
    queue); return it."""
    session.add(run)
    session.commit()
    if executor is not None:
        executor.submit(run.id)
    return run


def execute_claimed_run(
    factory: sessionmaker[Session],
    run_id: int,
    owner: str,
    cancel: threading.Event | None = None,
) -> str | None:
    """Execute a run `owner` has claimed; return its final status, None when the attempt lost
    its claim (nothing of it is written)."""
    attempt = Attempt(factory, run_id, owner, cancel)
    with factory() as session:
        run = session.get(CalibrationRun, run_id)
        if run is None:
            return None
        outcome: dict[str, Any]
        try:
            result = kind_of(run.kind).compute(session, run, attempt.progress)
            outcome = {
                "status": RUN_SUCCEEDED,
                "result": stored_json(result),
                "error": None,
                "progress_stage": "done",
                "progress_fraction": 1.0,
            }
        except JobCancelled:
            log.info("run %d: attempt abandoned (%s)", run_id, "claim lost or worker stopping")
            return None
        except Exception as exc:
            outcome = {"status": RUN_FAILED, "error": failure(exc, f"calibration run {run_id}")}
        session.rollback()  # the run was only read; its row is written by the conditional UPDATE
        if not attempt.finish(session, **outcome):
            log.warning("run %d: finished after its claim was lost; outcome discarded", run_id)
            return None
        return str(outcome["status"])


class RunExecutor(JobEngine):
    """The job engine of calibration runs: claims queued runs from the database and executes
    up to `workers` at a time, re-queueing those whose worker died. The API process
    (INTSPACE_RUN_EXECUTOR=local) and `intspace worker` run the same executor."""

    def __init__(
        self,
        factory: sessionmaker[Session],
        workers: int,
        policy: LeasePolicy | None = None,
        *,
        poll_s: float = 1.0,
        owner: str | None = None,
        on_finished: Callable[[int, str | None], None] | None = None,
    ) -> None:
        def execute(lease: Lease) -> str | None:
            return execute_claimed_run(factory, lease.job_id, lease.owner, lease.cancel)

        super().__init__(
            factory,
            RUNS,
            execute,
            workers,
            policy or LeasePolicy(),
            name="run",
            poll_s=poll_s,
            owner=owner,
            on_finished=on_finished,
        )

    def submit(self, run_id: int) -> None:
        """Say that run `run_id` was queued (committed): claim it without waiting for the next
        poll, if a slot is free."""
        del run_id  # the oldest queued run is claimed first, whichever it is
        self.wake()

    def shutdown(self, reason: str = "interrupted by service shutdown") -> int:
        """Stop claiming and hand the runs in progress back to the queue, or mark them
        interrupted with `reason` once claimed `max_attempts` times; return how many."""
        return super().shutdown(reason)
