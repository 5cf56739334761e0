"""Which process runs a space's tracker: a PostgreSQL advisory lock per space.

Where several `intspace serve` processes share one PostgreSQL database, each space has one
tracker, in the process that holds the space's session-level advisory lock
(`pg_try_advisory_lock(NAMESPACE, space id)`) on a dedicated connection. PostgreSQL frees the
lock when that connection ends, so a process that dies (SIGKILL, power loss: its socket closes)
hands its spaces on; the others try for the free locks every second and the first to get one
takes the space over (server.services.tracking). Locks are not re-entrant across connections:
only one process holds a space at a time.

The connection has TCP keepalives, so a peer that vanishes without closing its socket (a
cable pulled) loses its locks within about `_KEEPALIVE_S` seconds rather than the system's
default of hours; a holder checks its connection on every `poll` and gives up its spaces as
soon as it finds it broken.

Which process holds which space: the lock connection's application name is
`intspace-tracker-locks:<process id>`, so

    SELECT a.application_name, l.objid AS space FROM pg_locks l JOIN pg_stat_activity a
    USING (pid) WHERE l.locktype = 'advisory' AND l.classid = 1953655666 AND l.granted
    AND a.datname = current_database();

lists them (1953655666 is `NAMESPACE`; space 0 stands for cameras without a space).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable
from typing import Any

import psycopg

from server.services.fanout import conninfo

log = logging.getLogger(__name__)

# The first key of the two-key advisory lock: what the lock is for ("trackers" in ASCII).
NAMESPACE = 0x74726B72
_KEEPALIVE_S = 5
APPLICATION_NAME = "intspace-tracker-locks"


def lock_key(space_id: int | None) -> int:
    """Return the second advisory lock key of a space (0 for cameras without a space)."""
    return 0 if space_id is None else int(space_id)


class SpaceLocks:
    """The advisory locks this process holds, one per space, on one dedicated connection."""

    def __init__(self, database_url: str) -> None:
        self._conninfo = conninfo(database_url)
        self._conn: psycopg.Connection[Any] | None = None
        self._held: set[int | None] = set()

    @property
    def held(self) -> frozenset[int | None]:
        """The spaces whose lock this process holds."""
        return frozenset(self._held)

    def holds(self, space_id: int | None) -> bool:
        """Whether this process holds the lock of `space_id`."""
        return space_id in self._held

    def poll(self, spaces: Iterable[int | None]) -> tuple[set[int | None], set[int | None]]:
        """Check the connection and try for the free locks of `spaces`; return (acquired,
        lost): the spaces this call took, and those given up because the connection broke."""
        lost: set[int | None] = set()
        if self._conn is not None and self._conn.closed:
            # The connection broke since the last poll: its locks went with it.
            lost, self._held = set(self._held), set()
            self._conn = None
        try:
            conn = self._connect()
            conn.execute("SELECT 1")
        except psycopg.Error as exc:
            lost |= self._held
            self._held.clear()
            self._close()
            if lost:
                log.warning("tracker locks lost with their connection: %s", exc)
            return set(), lost
        wanted = sorted({s for s in spaces if s not in self._held}, key=lock_key)
        if not wanted:
            return set(), lost
        try:
            rows = conn.execute(
                "SELECT k, pg_try_advisory_lock(%s, k) FROM unnest(%s::int[]) AS k",
                (NAMESPACE, [lock_key(s) for s in wanted]),
            ).fetchall()
        except psycopg.Error as exc:
            log.warning("trying the tracker locks failed: %s", exc)
            lost = set(self._held)
            self._held.clear()
            self._close()
            return set(), lost
        got = {k for k, ok in rows if ok}
        acquired = {s for s in wanted if lock_key(s) in got}
        self._held |= acquired
        return acquired, lost

    def release(self, space_id: int | None) -> None:
        """Give up the lock of one space."""
        if space_id not in self._held:
            return
        self._held.discard(space_id)
        if self._conn is not None and not self._conn.closed:
            try:
                self._conn.execute(
                    "SELECT pg_advisory_unlock(%s, %s)", (NAMESPACE, lock_key(space_id))
                )
            except psycopg.Error:
                self._close()

    def close(self) -> None:
        """Give up every lock (closing the connection frees them)."""
        self._held.clear()
        self._close()

    def _connect(self) -> psycopg.Connection[Any]:
        if self._conn is None or self._conn.closed:
            self._conn = psycopg.connect(
                self._conninfo,
                autocommit=True,
                connect_timeout=5,
                keepalives=1,
                keepalives_idle=_KEEPALIVE_S,
                keepalives_interval=1,
                keepalives_count=3,
                # Who holds which space, for an operator (and the tests): pg_locks joined to
                # pg_stat_activity names the process.
                application_name=f"{APPLICATION_NAME}:{os.getpid()}",
            )
        return self._conn

    def _close(self) -> None:
        if self._conn is not None:
            try:
                self._conn.close()
            except psycopg.Error:
                pass
            self._conn = None
