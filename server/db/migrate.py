"""Alembic driven from code: upgrade to head at start (backing the SQLite file up first when a
migration is pending), report the current revision."""

from __future__ import annotations

import sqlite3
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Connection, Engine, inspect, text
from sqlalchemy.engine import make_url

REPO_ROOT = Path(__file__).resolve().parents[2]


def alembic_config(database_url: str) -> Config:
    """Return the Alembic configuration of the repository, pointed at `database_url`."""
    config = Config(str(REPO_ROOT / "alembic.ini"))
    config.set_main_option("script_location", str(REPO_ROOT / "migrations"))
    # Passed as an attribute, not through the ini, so '%' in passwords needs no escaping.
    config.attributes["database_url"] = database_url
    return config


@dataclass(frozen=True)
class SchemaState:
    """Where the database stands: its current revision and the head of the migrations."""

    current: str | None
    head: str | None

    @property
    def pending(self) -> bool:
        """Return True when the database is not at the head revision."""
        return self.current != self.head


def schema_state(engine: Engine, database_url: str) -> SchemaState:
    """Return the database's current revision and the scripts' head."""
    script = ScriptDirectory.from_config(alembic_config(database_url))
    with engine.connect() as connection:
        current = MigrationContext.configure(connection).get_current_revision()
    return SchemaState(current=current, head=script.get_current_head())


def backup_sqlite(database_url: str, label: str) -> Path | None:
    """Copy the SQLite file next to itself (consistent, WAL included); return the copy's path,
    None when there is no file yet."""
    path = make_url(database_url).database
    if not path or path == ":memory:" or not Path(path).exists():
        return None
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
    target = Path(f"{path}.{stamp}.{label}.bak")
    source = sqlite3.connect(path)
    try:
        dest = sqlite3.connect(target)
        try:
            source.backup(dest)
        finally:
            dest.close()
    finally:
        source.close()
    return target


def _has_tables(engine: Engine) -> bool:
    return bool(inspect(engine).get_table_names())


# The advisory lock key that serialises migrations of one PostgreSQL database ("isMG").
_MIGRATION_LOCK = 0x69734D47


def upgrade_to_head(engine: Engine, database_url: str) -> Path | None:
    """Apply pending migrations; SQLite files are backed up first. Return the backup's path.

    On PostgreSQL, several processes started at once on one database take turns by an
    advisory lock held for the whole upgrade; each looks again at what is pending once it holds
    the lock, so the later ones find nothing to do."""
    state = schema_state(engine, database_url)
    if not state.pending:
        return None
    if engine.dialect.name == "postgresql":
        with engine.connect() as lock:
            lock.execute(text("SELECT pg_advisory_lock(:k)"), {"k": _MIGRATION_LOCK})
            try:
                if schema_state(engine, database_url).pending:
                    command.upgrade(alembic_config(database_url), "head")
            finally:
                lock.execute(text("SELECT pg_advisory_unlock(:k)"), {"k": _MIGRATION_LOCK})
                lock.commit()
        return None
    backup = None
    if engine.dialect.name == "sqlite" and _has_tables(engine):
        backup = backup_sqlite(database_url, f"before-{state.head}")
    command.upgrade(alembic_config(database_url), "head")
    return backup


def current_revision(connection: Connection) -> str | None:
    """Return the database's Alembic revision, None when it was never migrated."""
    return MigrationContext.configure(connection).get_current_revision()
