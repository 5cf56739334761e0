"""Alembic migrations on SQLite and PostgreSQL: upgrade, downgrade, and a schema equal to the
models (autogenerate finds nothing to do)."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest
from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy import inspect

from server.db.base import Base
from server.db.migrate import alembic_config, schema_state, upgrade_to_head
from server.db.session import make_engine


@pytest.fixture(params=["sqlite", "postgresql"])
def empty_database_url(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    """Return the URL of an empty database: a new SQLite file or a new PostgreSQL database."""
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'migrations.sqlite3'}"
    return request.getfixturevalue("make_postgres_database")()


def _diffs(engine) -> list:
    with engine.connect() as connection:
        context = MigrationContext.configure(
            connection, opts={"compare_type": True, "render_as_batch": True}
        )
        return compare_metadata(context, Base.metadata)


def test_upgrade_downgrade_upgrade_matches_models(empty_database_url):
    config = alembic_config(empty_database_url)
    engine = make_engine(empty_database_url, pool_size=1)
    try:
        command.upgrade(config, "head")
        assert _diffs(engine) == []
        tables = set(inspect(engine).get_table_names())
        assert set(Base.metadata.tables) <= tables

        command.downgrade(config, "base")
        engine.dispose()  # reflect afresh
        assert set(inspect(engine).get_table_names()) <= {"alembic_version"}

        command.upgrade(config, "head")
        engine.dispose()
        assert _diffs(engine) == []
        state = schema_state(engine, empty_database_url)
        assert state.current == state.head and not state.pending
    finally:
        engine.dispose()


def test_sqlite_is_backed_up_before_a_pending_migration(tmp_path):
    path = tmp_path / "intspace.sqlite3"
    url = f"sqlite:///{path}"
    engine = make_engine(url, pool_size=1)
    try:
        assert upgrade_to_head(engine, url) is None  # a new database has nothing to save
        assert upgrade_to_head(engine, url) is None  # nothing pending
        command.downgrade(alembic_config(url), "base")
        engine.dispose()
        backup = upgrade_to_head(engine, url)
        assert backup is not None and backup.exists()
        with sqlite3.connect(backup) as copy:
            names = {r[0] for r in copy.execute("SELECT name FROM sqlite_master")}
        assert "alembic_version" in names
        with engine.connect() as connection:
            mode = connection.exec_driver_sql("PRAGMA journal_mode").scalar()
            keys = connection.exec_driver_sql("PRAGMA foreign_keys").scalar()
        assert (mode, keys) == ("wal", 1)
    finally:
        engine.dispose()


def test_runs_left_running_before_leases_are_requeued(empty_database_url):
    from sqlalchemy import text

    from server.db.session import make_session_factory
    from server.services.runs import LeasePolicy, release_expired_runs

    config = alembic_config(empty_database_url)
    engine = make_engine(empty_database_url, pool_size=1)
    try:
        command.upgrade(config, "0003")
        with engine.begin() as connection:
            for status, started in (("running", True), ("succeeded", True), ("queued", False)):
                connection.execute(
                    text(
                        "INSERT INTO calibration_runs (kind, source, status, inputs, options, "
                        "started_at) VALUES ('intrinsics', 'correspondences', :status, '{}', "
                        "'{}', :started)"
                    ),
                    {"status": status, "started": "2026-01-01 00:00:00" if started else None},
                )
        command.upgrade(config, "0004")
        engine.dispose()
        with engine.connect() as connection:
            rows = connection.execute(
                text("SELECT status, attempts, lease_expires_at FROM calibration_runs ORDER BY id")
            ).all()
        assert [tuple(r) for r in rows] == [
            ("running", 1, None),
            ("succeeded", 1, None),
            ("queued", 0, None),
        ]
        # Without a lease, the run left running counts as expired: back to the queue.
        command.upgrade(config, "head")
        with make_session_factory(engine)() as session:
            released = release_expired_runs(session, LeasePolicy())
        assert (released.requeued, released.given_up) == (1, 0)
    finally:
        engine.dispose()
