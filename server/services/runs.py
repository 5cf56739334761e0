"""Calibration runs: queued in the database, claimed under a lease and executed off the event
loop (threads of the API process, or `intspace worker` processes), finished exactly once.

A claim is a lease: the claiming worker holds the run until `lease_expires_at` and renews that
by heartbeat while it computes. A worker that dies (SIGKILL, power loss) stops renewing; once
its lease has expired any worker re-queues the run, or fails it with the reason after
`max_attempts` claims. A worker that stops on purpose hands its runs back to the queue at once
(interrupted after `max_attempts` claims). Queued runs stay queued whatever happens to the
workers. Every write of an attempt (progress, result, error) is conditional on its worker
still holding the claim, so an attempt that lost its claim writes nothing: a run's result is
written once. What a run computes is its kind's (server.services.calibration.kinds)."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Collection
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import TYPE_CHECKING, Any

from sqlalchemy import and_, or_, select, update
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
)
from server.services.calibration import kind_of
from server.services.jobs import rows_changed, worker_id

if TYPE_CHECKING:
    from server.settings import Settings

log = logging.getLogger(__name__)


class RunCancelled(Exception):
    """The attempt lost its claim (its lease expired and the run was re-queued, or its worker
    is stopping): it ends at this safe point without writing anything."""


@dataclass(frozen=True)
class LeasePolicy:
    """How claims on runs are held: a claim lasts `lease_s` seconds unless renewed, renewed
    every `heartbeat_s` seconds, and a run is given up after `max_attempts` claims."""

    lease_s: float = 30.0
    heartbeat_s: float = 5.0
    max_attempts: int = 3

    def __post_init__(self) -> None:
        if not self.lease_s > 0 or not 0 < self.heartbeat_s < self.lease_s:
            raise ValueError(
                f"the heartbeat ({self.heartbeat_s} s) must be positive and shorter than the "
                f"lease ({self.lease_s} s), or every claim expires between two renewals"
            )
        if self.max_attempts < 1:
            raise ValueError(f"max_attempts must be at least 1, got {self.max_attempts}")

    @classmethod
    def from_settings(cls, settings: Settings) -> LeasePolicy:
        """Return the policy of INTSPACE_RUN_LEASE_S, _RUN_HEARTBEAT_S and _RUN_MAX_ATTEMPTS."""
        return cls(settings.run_lease_s, settings.run_heartbeat_s, settings.run_max_attempts)

    def expiry(self, now: datetime | None = None) -> datetime:
        """Return when a claim taken or renewed `now` expires."""
        return (now or utcnow()) + timedelta(seconds=self.lease_s)


def claim_run(session: Session, run_id: int, owner: str, policy: LeasePolicy) -> bool:
    """Move run `run_id` from queued to running under a lease held by `owner`; return False
    when someone else has it. The conditional UPDATE is atomic on SQLite and PostgreSQL."""
    now = utcnow()
    result = session.execute(
        update(CalibrationRun)
        .where(CalibrationRun.id == run_id, CalibrationRun.status == RUN_QUEUED)
        .values(
            status=RUN_RUNNING,
            attempts=CalibrationRun.attempts + 1,
            lease_owner=owner,
            lease_expires_at=policy.expiry(now),
            started_at=now,
            finished_at=None,
            progress_stage="starting",
            progress_fraction=0.0,
        )
    )
    session.commit()
    return rows_changed(result) == 1


def claim_next_run(session: Session, owner: str, policy: LeasePolicy) -> int | None:
    """Claim the oldest queued run for `owner`; return its id, None when the queue is empty.
    On PostgreSQL the row is locked with SKIP LOCKED, so concurrent workers never wait on each
    other."""
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
    return run_id if claim_run(session, run_id, owner, policy) else None


def _held_by(owner: str, run_ids: Collection[int]) -> Any:
    return and_(
        CalibrationRun.id.in_(list(run_ids)),
        CalibrationRun.status == RUN_RUNNING,
        CalibrationRun.lease_owner == owner,
    )


def renew_leases(
    session: Session, owner: str, run_ids: Collection[int], policy: LeasePolicy
) -> set[int]:
    """Extend `owner`'s leases on `run_ids`; return the ids it no longer holds (re-queued by
    another worker after its lease expired, or finished)."""
    if not run_ids:
        return set()
    session.execute(
        update(CalibrationRun)
        .where(_held_by(owner, run_ids))
        .values(lease_expires_at=policy.expiry())
    )
    held = set(session.scalars(select(CalibrationRun.id).where(_held_by(owner, run_ids))))
    session.commit()
    return set(run_ids) - held


@dataclass(frozen=True)
class Released:
    """Runs whose claims ended without a result: back in the queue, or given up."""

    requeued: int
    given_up: int

    @property
    def total(self) -> int:
        return self.requeued + self.given_up


def _release(
    session: Session, claimed: Any, policy: LeasePolicy, give_up_status: str, reason: str
) -> Released:
    now = utcnow()
    requeued = rows_changed(
        session.execute(
            update(CalibrationRun)
            .where(claimed, CalibrationRun.attempts < policy.max_attempts)
            .values(
                status=RUN_QUEUED,
                lease_owner=None,
                lease_expires_at=None,
                progress_stage=None,
                progress_fraction=None,
            )
        )
    )
    given_up = rows_changed(
        session.execute(
            update(CalibrationRun)
            .where(claimed, CalibrationRun.attempts >= policy.max_attempts)
            .values(
                status=give_up_status,
                error=f"{reason}, {policy.max_attempts} time(s): given up",
                finished_at=now,
                lease_owner=None,
                lease_expires_at=None,
            )
        )
    )
    session.commit()
    return Released(requeued, given_up)


def release_expired_runs(session: Session, policy: LeasePolicy) -> Released:
    """Re-queue the running runs whose lease has expired (their worker died), or fail them
    with the reason once they have been claimed `max_attempts` times. A run without a lease
    (left running before leases existed) counts as expired. Queued runs are not touched."""
    expired = and_(
        CalibrationRun.status == RUN_RUNNING,
        or_(CalibrationRun.lease_expires_at.is_(None), CalibrationRun.lease_expires_at < utcnow()),
    )
    released = _release(
        session, expired, policy, RUN_FAILED, "its worker stopped before finishing it"
    )
    if released.total:
        log.warning(
            "runs whose worker stopped renewing its lease: %d re-queued, %d failed",
            released.requeued,
            released.given_up,
        )
    return released


def release_own_runs(
    session: Session, owner: str, run_ids: Collection[int], policy: LeasePolicy, reason: str
) -> Released:
    """Hand `owner`'s runs back to the queue (a graceful stop), or mark them interrupted with
    `reason` once they have been claimed `max_attempts` times."""
    if not run_ids:
        return Released(0, 0)
    return _release(session, _held_by(owner, run_ids), policy, RUN_INTERRUPTED, reason)


class Attempt:
    """One worker's attempt at a claimed run: reports progress (stage, fraction 0-1) while its
    claim holds and raises RunCancelled at the next report once it does not. Reports are
    written at most every `min_interval_s` unless the stage changes."""

    def __init__(
        self,
        factory: sessionmaker[Session],
        run_id: int,
        owner: str,
        cancel: threading.Event | None = None,
        min_interval_s: float = 0.25,
    ) -> None:
        self.factory = factory
        self.run_id = run_id
        self.owner = owner
        self.cancel = cancel or threading.Event()
        self._min_interval_s = min_interval_s
        self._last: tuple[str, float] | None = None

    def _held(self) -> Any:
        return _held_by(self.owner, (self.run_id,))

    def progress(self, stage: str, fraction: float) -> None:
        """Record how far the attempt has come; raise RunCancelled when it lost its claim."""
        if self.cancel.is_set():
            raise RunCancelled(f"run {self.run_id}: the claim was withdrawn")
        now = time.monotonic()
        if self._last is not None and self._last[0] == stage:
            if now - self._last[1] < self._min_interval_s:
                return
        with self.factory() as session:
            result = session.execute(
                update(CalibrationRun)
                .where(self._held())
                .values(progress_stage=stage[:80], progress_fraction=min(max(fraction, 0.0), 1.0))
            )
            session.commit()
        if rows_changed(result) != 1:
            self.cancel.set()
            raise RunCancelled(f"run {self.run_id}: the claim was lost")
        self._last = (stage, now)

    def finish(self, session: Session, **values: Any) -> bool:
        """Write the attempt's outcome if it still holds the claim; return whether it did."""
        result = session.execute(
            update(CalibrationRun)
            .where(self._held())
            .values(finished_at=utcnow(), lease_owner=None, lease_expires_at=None, **values)
        )
        session.commit()
        return rows_changed(result) == 1


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
                "result": result,
                "error": None,
                "progress_stage": "done",
                "progress_fraction": 1.0,
            }
        except RunCancelled:
            log.info("run %d: attempt abandoned (%s)", run_id, "claim lost or worker stopping")
            return None
        except IntspaceError as exc:
            outcome = {"status": RUN_FAILED, "error": f"{type(exc).__name__}: {exc}"}
        except Exception as exc:
            log.exception("calibration run %s crashed", run_id)
            outcome = {"status": RUN_FAILED, "error": f"internal error: {exc!r}"}
        session.rollback()  # the run was only read; its row is written by the conditional UPDATE
        if not attempt.finish(session, **outcome):
            log.warning("run %d: finished after its claim was lost; outcome discarded", run_id)
            return None
        return str(outcome["status"])


class RunExecutor:
    """Claims queued runs from the database and executes up to `workers` at a time, each in a
    daemon thread (numpy and OpenCV release the GIL in their heavy parts; a daemon thread can be
    abandoned at shutdown once its run is handed back). A heartbeat thread renews the leases of
    the runs it holds, withdraws those it lost, and re-queues runs whose lease expired. The API
    process (INTSPACE_RUN_EXECUTOR=local) and `intspace worker` run the same executor."""

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
        self._factory = factory
        self._workers = workers
        self.policy = policy or LeasePolicy()
        self.owner = owner or worker_id()
        self._poll_s = poll_s
        self._on_finished = on_finished
        self._held: dict[int, threading.Event] = {}
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._threads = [
            threading.Thread(target=self._dispatch, name="runs-dispatch", daemon=True),
            threading.Thread(target=self._heartbeat, name="runs-heartbeat", daemon=True),
        ]
        for thread in self._threads:
            thread.start()

    def submit(self, run_id: int) -> None:
        """Say that run `run_id` was queued (committed): claim it without waiting for the next
        poll, if a slot is free."""
        del run_id  # the oldest queued run is claimed first, whichever it is
        self._wake.set()

    def held(self) -> list[int]:
        """Return the ids of the runs this executor holds now."""
        with self._lock:
            return list(self._held)

    def _dispatch(self) -> None:
        first = True
        while not self._stop.is_set():
            try:
                if first:  # runs a stopped worker left behind are claimable before the heartbeat
                    with self._factory() as session:
                        release_expired_runs(session, self.policy)
                    first = False
                self._claim_while_free()
            except Exception:  # the database may be away for a while: retry at the next poll
                log.exception("claiming calibration runs failed")
            self._wake.wait(self._poll_s)
            self._wake.clear()

    def _claim_while_free(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                if len(self._held) >= self._workers:
                    return
            with self._factory() as session:
                run_id = claim_next_run(session, self.owner, self.policy)
            if run_id is None:
                return
            cancel = threading.Event()
            with self._lock:
                self._held[run_id] = cancel
            log.info("run %d claimed by %s", run_id, self.owner)
            threading.Thread(
                target=self._execute, args=(run_id, cancel), name=f"run-{run_id}", daemon=True
            ).start()

    def _execute(self, run_id: int, cancel: threading.Event) -> None:
        status: str | None = None
        try:
            status = execute_claimed_run(self._factory, run_id, self.owner, cancel)
            log.info("run %d %s", run_id, status or "abandoned")
        except Exception:
            log.exception("calibration run %s could not be executed", run_id)
        finally:
            with self._lock:
                self._held.pop(run_id, None)
            self._wake.set()
            if self._on_finished is not None:
                self._on_finished(run_id, status)

    def _heartbeat(self) -> None:
        while not self._stop.wait(self.policy.heartbeat_s):
            try:
                with self._lock:
                    held = dict(self._held)
                with self._factory() as session:
                    for run_id in renew_leases(session, self.owner, held, self.policy):
                        log.warning("run %d: claim lost; stopping its attempt", run_id)
                        held[run_id].set()
                    if release_expired_runs(session, self.policy).requeued:
                        self._wake.set()
            except Exception:
                log.exception("renewing calibration run leases failed")

    def shutdown(self, reason: str = "interrupted by service shutdown") -> int:
        """Stop claiming, withdraw the runs in progress (each stops at its next safe point and
        writes nothing) and hand them back to the queue, or mark them interrupted with `reason`
        once claimed `max_attempts` times; return how many were handed back or interrupted."""
        self._stop.set()
        self._wake.set()
        # A claim the dispatcher is making now is held by the time it has stopped.
        dispatcher, heartbeat = self._threads
        dispatcher.join(timeout=5.0)
        with self._lock:
            held = dict(self._held)
        for cancel in held.values():
            cancel.set()
        with self._factory() as session:
            released = release_own_runs(session, self.owner, held, self.policy, reason)
        heartbeat.join(timeout=5.0)
        return released.total
