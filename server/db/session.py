"""Engine and session factory: SQLite in WAL mode with foreign keys on, PostgreSQL as is.

A SQLite file deleted (or replaced) under a running service is still open: writes into it
succeed and are lost. Every commit therefore checks that the file it writes is the one on disk
and raises `StorageFailure` otherwise, so that the write fails loudly (503) instead.
"""

from __future__ import annotations

import os
import weakref
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.engine import make_url
from sqlalchemy.orm import Session, sessionmaker


class StorageFailure(Exception):
    """The database's storage is gone or unusable (e.g. its data directory was deleted)."""


def _configure_sqlite_connection(dbapi_connection: Any, _record: Any) -> None:
    # WAL lets readers run while a run's result is written; foreign keys are off by default.
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA journal_mode=WAL")
    cursor.execute("PRAGMA foreign_keys=ON")
    cursor.execute("PRAGMA synchronous=NORMAL")
    cursor.execute("PRAGMA busy_timeout=10000")
    cursor.close()


class SqliteFileGuard:
    """Remembers the identity (device, inode) of the SQLite file when the engine opens it and
    tells whether the path still names that file."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._identity: tuple[int, int] | None = None

    def opened(self, *_: Any) -> None:
        """Record the file's identity (first connection wins: later ones must agree)."""
        if self._identity is None:
            st = os.stat(self.path)
            self._identity = (st.st_dev, st.st_ino)

    def problem(self) -> str | None:
        """Return why the database file is unusable, None when it is fine."""
        try:
            st = os.stat(self.path)
        except FileNotFoundError:
            return f"the database file {self.path} was deleted while the service ran"
        except OSError as exc:
            return f"the database file {self.path} cannot be read: {exc.strerror}"
        if self._identity is not None and (st.st_dev, st.st_ino) != self._identity:
            return f"the database file {self.path} was replaced while the service ran"
        if not os.access(self.path.parent, os.W_OK) or not os.access(self.path, os.W_OK):
            return f"the database file {self.path} or its directory is not writable"
        return None

    def before_commit(self, _connection: Any) -> None:
        """Raise StorageFailure instead of committing into a file that is gone."""
        problem = self.problem()
        if problem is not None:
            raise StorageFailure(problem)


_GUARDS: weakref.WeakKeyDictionary[Engine, SqliteFileGuard] = weakref.WeakKeyDictionary()


def make_engine(url: str, *, pool_size: int = 40) -> Engine:
    """Return an engine for `url`; SQLite files get their directory created and WAL mode."""
    parsed = make_url(url)
    if parsed.get_backend_name() == "sqlite":
        guard = None
        if parsed.database and parsed.database != ":memory:":
            path = Path(parsed.database)
            path.parent.mkdir(parents=True, exist_ok=True)
            guard = SqliteFileGuard(path.resolve())
        engine = create_engine(
            url,
            connect_args={"check_same_thread": False, "timeout": 10},
            pool_size=pool_size,
            max_overflow=pool_size,
        )
        event.listen(engine, "connect", _configure_sqlite_connection)
        if guard is not None:
            event.listen(engine, "connect", guard.opened)
            event.listen(engine, "commit", guard.before_commit)
            _GUARDS[engine] = guard
        return engine
    return create_engine(url, pool_size=pool_size, max_overflow=pool_size, pool_pre_ping=True)


def storage_problem(engine: Engine) -> str | None:
    """Return why the engine's storage is failing (a SQLite file deleted, replaced or not
    writable), None when nothing is known to be wrong."""
    guard = _GUARDS.get(engine)
    return guard.problem() if guard is not None else None


def make_session_factory(engine: Engine) -> sessionmaker[Session]:
    """Return the session factory; objects stay readable after commit (no expiry)."""
    return sessionmaker(engine, expire_on_commit=False)


def session_scope(factory: sessionmaker[Session]) -> Iterator[Session]:
    """Yield a session closed afterwards (the caller commits)."""
    with factory() as session:
        yield session
