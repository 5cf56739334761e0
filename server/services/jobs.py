"""The service's one job engine: calibration runs, robot tasks and path follows are jobs held
under leases, stored in one column shape on their tables (server.db.models.Leased: the
lease's owner, its expiry, the holder's last heartbeat and the claims made so far).

A claim is a lease: a conditional UPDATE (atomic on SQLite and PostgreSQL, taken when it
changed exactly the row it meant) moves a job to running under `lease_owner` until
`lease_expires_at`; the engine that holds it renews that by heartbeat while the job runs.
A holder that dies (SIGKILL, power loss) stops renewing; once its lease has expired any engine
of the same kind re-queues the job, or gives it up with the reason after `max_attempts`
claims (a kind without a queue, whose jobs are started by the process that accepted them,
gives it up at once). An engine that stops on purpose hands its jobs back the same way. Every
write of a holding (progress, result, error) is conditional on its holder still holding the
lease, so a holder that lost it writes nothing: a job's outcome is written once."""

from __future__ import annotations

import logging
import os
import socket
import threading
import uuid
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from typing import TYPE_CHECKING, Any, cast

from sqlalchemy import and_, or_, select, update
from sqlalchemy.engine import CursorResult, Result
from sqlalchemy.orm import Session, sessionmaker

from core.errors import IntspaceError
from server.db.base import utcnow

if TYPE_CHECKING:
    from server.settings import Settings

log = logging.getLogger(__name__)


def worker_id() -> str:
    """Return a name for this executor that no other process shares: host, pid and a nonce
    (a pid is reused after a restart, the nonce is not)."""
    return f"{socket.gethostname()[:80]}:{os.getpid()}:{uuid.uuid4().hex[:8]}"


def rows_changed(result: Result[Any]) -> int:
    """Return how many rows the UPDATE whose result this is changed (a claim, a renewal or a
    write conditional on holding one is taken when it changed exactly the row it meant)."""
    return int(cast(CursorResult[Any], result).rowcount or 0)


def failure(exc: Exception, job: str) -> str:
    """Return the error a job that raised `exc` ends with: a typed error's name and message
    (IntspaceError: the inputs were refused), else "internal error" with the exception, whose
    traceback is logged (called in the handler, naming the `job`)."""
    if isinstance(exc, IntspaceError):
        return f"{type(exc).__name__}: {exc}"
    log.exception("%s crashed", job)
    return f"internal error: {exc!r}"


class JobCancelled(Exception):
    """The holding lost its lease (it expired and the job was re-queued or given up, the job
    was deleted, or its engine is stopping): it ends at this safe point without writing."""


@dataclass(frozen=True)
class LeasePolicy:
    """How leases on jobs are held: a lease lasts `lease_s` seconds unless renewed, renewed
    every `heartbeat_s` seconds, and a job is given up after `max_attempts` claims."""

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
        """Return the calibration runs' policy: INTSPACE_RUN_LEASE_S, _RUN_HEARTBEAT_S and
        _RUN_MAX_ATTEMPTS."""
        return cls(settings.run_lease_s, settings.run_heartbeat_s, settings.run_max_attempts)

    def expiry(self, now: datetime | None = None) -> datetime:
        """Return when a lease taken or renewed `now` expires."""
        return (now or utcnow()) + timedelta(seconds=self.lease_s)

    def lease(self, owner: str, now: datetime | None = None) -> dict[str, Any]:
        """Return the lease columns of a job `owner` takes `now`, as its first claim (a job
        stored already held by the process that accepts it)."""
        now = now or utcnow()
        return {
            "lease_owner": owner,
            "lease_expires_at": self.expiry(now),
            "heartbeat_at": now,
            "attempts": 1,
        }


def given_up_after(reason: str, attempts: int) -> str:
    """Return the error of a job given up after `attempts` claims, each ended for `reason`."""
    return f"{reason}, {attempts} time(s): given up"


def _reason_only(reason: str, attempts: int) -> str:
    del attempts  # a job that is never re-queued was claimed once
    return reason


@dataclass(frozen=True)
class JobTable:
    """Where one kind of job is stored: its model (with the Leased columns), its status
    column and statuses, and what its claims and re-queues reset. `queued` is the status of a
    job any engine may claim; None for a kind whose jobs are held from the moment a process
    accepts them, and given up (never re-queued) when their holder stops."""

    model: Any
    status: Any
    running: str
    held: tuple[str, ...]
    expired_reason: str  # why a job is given up when its holder's lease expired
    expired_status: str = "failed"
    queued: str | None = None
    claimed: Mapping[str, Any] = field(default_factory=dict)
    requeued: Mapping[str, Any] = field(default_factory=dict)
    interrupted: str = "interrupted"
    given_up: Callable[[str, int], str] = _reason_only
    error: str = "error"
    started: str | None = None  # the column a claim sets to when it was taken
    finished: str = "finished_at"

    def holding(self, owner: str, job_ids: Collection[int]) -> Any:
        """Return the condition: the jobs `job_ids` that `owner` holds now."""
        return and_(
            self.model.id.in_(list(job_ids)),
            self.status.in_(self.held),
            self.model.lease_owner == owner,
        )

    def expired(self, now: datetime | None = None) -> Any:
        """Return the condition: the held jobs whose lease has expired (a job without a lease,
        left running before leases existed, counts as expired)."""
        return and_(
            self.status.in_(self.held),
            or_(
                self.model.lease_expires_at.is_(None),
                self.model.lease_expires_at < (now or utcnow()),
            ),
        )


def lease_expired(row: Any, now: datetime | None = None) -> bool:
    """Return whether a loaded job row's lease has expired by `now` (JobTable.expired, read
    on a row: no lease counts as expired)."""
    expires = row.lease_expires_at
    if expires is None:
        return True
    if expires.tzinfo is None:  # SQLite hands timestamps back naive; they were written in UTC
        expires = expires.replace(tzinfo=UTC)
    return bool(expires < (now or utcnow()))


def claim(
    session: Session,
    table: JobTable,
    job_id: int,
    owner: str,
    policy: LeasePolicy,
    claimable: Any = None,
    **values: Any,
) -> bool:
    """Move job `job_id` to running under a lease held by `owner`, if it is `claimable`
    (default: queued), with the kind's claim values and `values`; return False when someone
    else has it. The conditional UPDATE is atomic on SQLite and PostgreSQL."""
    if claimable is None:
        claimable = table.status == table.queued
    now = utcnow()
    result = session.execute(
        update(table.model)
        .where(table.model.id == job_id, claimable)
        .values(
            {
                table.status.key: table.running,
                "attempts": table.model.attempts + 1,
                "lease_owner": owner,
                "lease_expires_at": policy.expiry(now),
                "heartbeat_at": now,
                **({} if table.started is None else {table.started: now}),
                **table.claimed,
                **values,
            }
        )
        .execution_options(synchronize_session=False)
    )
    session.commit()
    return rows_changed(result) == 1


def claim_next(session: Session, table: JobTable, owner: str, policy: LeasePolicy) -> int | None:
    """Claim the oldest queued job for `owner`; return its id, None when the queue is empty.
    On PostgreSQL the row is locked with SKIP LOCKED, so concurrent engines never wait on
    each other."""
    stmt = (
        select(table.model.id).where(table.status == table.queued).order_by(table.model.id).limit(1)
    )
    if session.get_bind().dialect.name == "postgresql":
        stmt = stmt.with_for_update(skip_locked=True)
    job_id = session.scalar(stmt)
    if job_id is None:
        session.rollback()
        return None
    return job_id if claim(session, table, job_id, owner, policy) else None


def renew(
    session: Session, table: JobTable, owner: str, job_ids: Collection[int], policy: LeasePolicy
) -> set[int]:
    """Extend `owner`'s leases on `job_ids`; return the ids it no longer holds (given to
    another engine after its lease expired, finished, or deleted)."""
    if not job_ids:
        return set()
    now = utcnow()
    session.execute(
        update(table.model)
        .where(table.holding(owner, job_ids))
        .values(lease_expires_at=policy.expiry(now), heartbeat_at=now)
        .execution_options(synchronize_session=False)
    )
    held = set(session.scalars(select(table.model.id).where(table.holding(owner, job_ids))))
    session.commit()
    return set(job_ids) - held


@dataclass(frozen=True)
class Released:
    """Jobs whose leases ended without an outcome: back in the queue, or given up."""

    requeued: int
    given_up: int

    @property
    def total(self) -> int:
        return self.requeued + self.given_up


def release(
    session: Session,
    table: JobTable,
    which: Any,
    policy: LeasePolicy,
    give_up_status: str,
    reason: str,
) -> Released:
    """Put the jobs `which` (held ones) back in the queue, or give them up with `reason` as
    `give_up_status` once claimed `max_attempts` times (at once for a kind without a queue)."""
    free = {"lease_owner": None, "lease_expires_at": None}
    requeued = 0
    if table.queued is not None:
        requeued = rows_changed(
            session.execute(
                update(table.model)
                .where(which, table.model.attempts < policy.max_attempts)
                .values({table.status.key: table.queued, **free, **table.requeued})
                .execution_options(synchronize_session=False)
            )
        )
    given_up = rows_changed(
        session.execute(
            update(table.model)
            .where(which)
            .values(
                {
                    table.status.key: give_up_status,
                    table.error: table.given_up(reason, policy.max_attempts),
                    table.finished: utcnow(),
                    **free,
                }
            )
            .execution_options(synchronize_session=False)
        )
    )
    session.commit()
    return Released(requeued, given_up)


def release_expired(session: Session, table: JobTable, policy: LeasePolicy) -> Released:
    """Re-queue the held jobs whose lease has expired (their holder died), or give them up
    as failed with the reason once claimed `max_attempts` times. Reads first, so that a call
    that finds none (nearly every one) writes nothing."""
    expired = table.expired()
    if session.scalar(select(table.model.id).where(expired).limit(1)) is None:
        session.rollback()  # ends the read's transaction, as the write's commit would
        return Released(0, 0)
    released = release(session, table, expired, policy, table.expired_status, table.expired_reason)
    if released.total:
        log.warning(
            "%s whose holder stopped renewing its lease: %d re-queued, %d given up",
            table.model.__tablename__,
            released.requeued,
            released.given_up,
        )
    return released


def release_own(
    session: Session,
    table: JobTable,
    owner: str,
    job_ids: Collection[int],
    policy: LeasePolicy,
    reason: str,
) -> Released:
    """Hand `owner`'s jobs back to the queue (a graceful stop), or mark them interrupted with
    `reason` once claimed `max_attempts` times."""
    if not job_ids:
        return Released(0, 0)
    return release(session, table, table.holding(owner, job_ids), policy, table.interrupted, reason)


class Lease:
    """One holder's lease on one job: its writes take effect only while the lease holds."""

    def __init__(
        self,
        factory: sessionmaker[Session],
        table: JobTable,
        job_id: int,
        owner: str,
        cancel: threading.Event | None = None,
    ) -> None:
        self.factory = factory
        self.table = table
        self.job_id = job_id
        self.owner = owner
        self.cancel = cancel or threading.Event()

    def held(self) -> Any:
        """Return the condition: the job, held by this lease's owner."""
        return self.table.holding(self.owner, (self.job_id,))

    def check(self) -> None:
        """Raise JobCancelled when the lease was withdrawn (lost, or the engine is stopping)."""
        if self.cancel.is_set():
            raise JobCancelled(f"{self.table.model.__tablename__} {self.job_id}: withdrawn")

    def write(self, **values: Any) -> None:
        """Write `values` on the job; raise JobCancelled when the lease no longer holds."""
        self.check()
        with self.factory() as session:
            result = session.execute(
                update(self.table.model)
                .where(self.held())
                .values(**values)
                .execution_options(synchronize_session=False)
            )
            session.commit()
        if rows_changed(result) != 1:
            self.cancel.set()
            raise JobCancelled(f"{self.table.model.__tablename__} {self.job_id}: lease lost")

    def finish(self, session: Session, **values: Any) -> bool:
        """Write the job's outcome and end the lease if it still holds; return whether it
        did."""
        result = session.execute(
            update(self.table.model)
            .where(self.held())
            .values(
                {self.table.finished: utcnow(), "lease_owner": None, "lease_expires_at": None}
                | values
            )
            .execution_options(synchronize_session=False)
        )
        session.commit()
        return rows_changed(result) == 1


Execute = Callable[[Lease], str | None]


class JobEngine:
    """Holds jobs of one kind and executes up to `workers` at a time, each in a daemon thread
    (numpy and OpenCV release the GIL in their heavy parts; a daemon thread can be abandoned
    at shutdown once its job is handed back). With a queue (the table's `queued`), a
    dispatcher thread claims the oldest queued jobs; otherwise the jobs are claimed by the
    process that accepts them and handed to `hold`. A heartbeat thread renews the leases of
    the jobs it holds, withdraws those it lost, and releases jobs whose lease expired.
    `execute(lease)` runs one job and returns its final status (None when it lost its lease);
    `on_finished(job_id, status)` is told when each ends."""

    def __init__(
        self,
        factory: sessionmaker[Session],
        table: JobTable,
        execute: Execute,
        workers: int,
        policy: LeasePolicy,
        *,
        name: str,
        poll_s: float = 1.0,
        owner: str | None = None,
        on_finished: Callable[[int, str | None], None] | None = None,
    ) -> None:
        self._factory = factory
        self.table = table
        self._job = execute
        self.workers = workers
        self.policy = policy
        self.owner = owner or worker_id()
        self._name = name
        self._poll_s = poll_s
        self._on_finished = on_finished
        self._held: dict[int, threading.Event] = {}
        self._waiting: list[int] = []  # held, not started (no free worker yet)
        self._threads: dict[int, threading.Thread] = {}
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._loops = [
            threading.Thread(target=self._dispatch, name=f"{name}-dispatch", daemon=True),
            threading.Thread(target=self._heartbeat, name=f"{name}-heartbeat", daemon=True),
        ]
        for thread in self._loops:
            thread.start()

    def hold(self, job_id: int) -> None:
        """Take over job `job_id`, stored (committed) with this engine's lease: its lease is
        renewed from now on, and it starts when a worker is free."""
        with self._lock:
            self._held[job_id] = threading.Event()
            self._waiting.append(job_id)
        self._wake.set()

    def wake(self) -> None:
        """Say that a job was queued: claim it without waiting for the next poll."""
        self._wake.set()

    def settle(self, session: Session) -> Released:
        """Release the jobs of this kind whose holder stopped (release_expired), so that a
        read never shows a job running that nothing runs."""
        return release_expired(session, self.table, self.policy)

    def held(self) -> list[int]:
        """Return the ids of the jobs this engine holds now, started or waiting."""
        with self._lock:
            return list(self._held)

    def _dispatch(self) -> None:
        first = True
        while not self._stop.is_set():
            try:
                if first:  # jobs a stopped engine left behind are claimable before the beat
                    with self._factory() as session:
                        release_expired(session, self.table, self.policy)
                    first = False
                self._start_while_free()
            except Exception:  # the database may be away for a while: retry at the next poll
                log.exception("claiming %s failed", self.table.model.__tablename__)
            self._wake.wait(self._poll_s)
            self._wake.clear()

    def _next(self) -> int | None:
        with self._lock:
            if len(self._threads) >= self.workers:
                return None
            if self._waiting:
                return self._waiting.pop(0)
        if self.table.queued is None:
            return None
        with self._factory() as session:
            job_id = claim_next(session, self.table, self.owner, self.policy)
        if job_id is not None:
            log.info("%s %d claimed by %s", self._name, job_id, self.owner)
            with self._lock:
                self._held[job_id] = threading.Event()
        return job_id

    def _start_while_free(self) -> None:
        while not self._stop.is_set():
            job_id = self._next()
            if job_id is None:
                return
            with self._lock:
                cancel = self._held.get(job_id)
                if cancel is None:  # released while it waited
                    continue
                thread = threading.Thread(
                    target=self._work,
                    args=(Lease(self._factory, self.table, job_id, self.owner, cancel),),
                    name=f"{self._name}-{job_id}",
                    daemon=True,
                )
                self._threads[job_id] = thread
            thread.start()

    def _work(self, lease: Lease) -> None:
        status: str | None = None
        try:
            status = self._job(lease)
            log.info("%s %d %s", self._name, lease.job_id, status or "abandoned")
        except Exception:
            log.exception("%s %d could not be executed", self._name, lease.job_id)
        finally:
            with self._lock:
                self._held.pop(lease.job_id, None)
                self._threads.pop(lease.job_id, None)
            self._wake.set()
            if self._on_finished is not None:
                self._on_finished(lease.job_id, status)

    def _heartbeat(self) -> None:
        while not self._stop.wait(self.policy.heartbeat_s):
            try:
                with self._lock:
                    held = dict(self._held)
                with self._factory() as session:
                    for job_id in renew(session, self.table, self.owner, held, self.policy):
                        log.warning("%s %d: lease lost; stopping it", self._name, job_id)
                        held[job_id].set()
                        with self._lock:
                            if job_id in self._waiting:
                                self._waiting.remove(job_id)
                                self._held.pop(job_id, None)
                    if release_expired(session, self.table, self.policy).requeued:
                        self._wake.set()
            except Exception:  # the database may be away for a while: retry at the next beat
                log.exception("renewing the leases of %s failed", self._name)

    def shutdown(self, reason: str) -> int:
        """Stop taking jobs, withdraw those in progress (each stops at its next safe point and
        writes nothing) and hand them back to the queue, or mark them interrupted with
        `reason` once claimed `max_attempts` times; return how many were handed back or
        interrupted."""
        self._stop.set()
        self._wake.set()
        # A claim the dispatcher is making now is held by the time it has stopped.
        dispatcher, heartbeat = self._loops
        dispatcher.join(timeout=5.0)
        with self._lock:
            held = dict(self._held)
            self._waiting.clear()
        for cancel in held.values():
            cancel.set()
        with self._factory() as session:
            released = release_own(session, self.table, self.owner, held, self.policy, reason)
        # A beat in progress ends before the service closes its database under it.
        heartbeat.join(timeout=5.0)
        return released.total
