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
    from server.services.jobs import LeasePolicy, release_expired
    from server.services.runs import RUNS

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
            released = release_expired(session, RUNS, LeasePolicy())
        assert (released.requeued, released.given_up) == (1, 0)
    finally:
        engine.dispose()


def test_task_and_follow_heartbeats_become_leases_and_back(empty_database_url):
    # Before 0011 a task kept its process and last sign of life (Unix s, stale after 60 s) and
    # a path's follow task its heartbeat (stale after 30 s); after it both hold a lease that
    # expires when that heartbeat went stale, and the downgrade gives the heartbeats back.
    from datetime import UTC, datetime, timedelta

    from sqlalchemy import text

    config = alembic_config(empty_database_url)
    engine = make_engine(empty_database_url, pool_size=1)
    beat = 1_790_000_000.25  # a Unix time with a fraction: the conversion keeps it
    try:
        command.upgrade(config, "0010_zones")
        with engine.begin() as connection:
            connection.execute(
                text("INSERT INTO spaces (id, name, description) VALUES (1, 'h', '')")
            )
            for status in ("running", "succeeded"):
                connection.execute(
                    text(
                        "INSERT INTO tasks (kind, status, inputs, owner, heartbeat) "
                        "VALUES ('fetch', :status, '{}', 'host:1:ab', :beat)"
                    ),
                    {"status": status, "beat": beat},
                )
            for status in ("running", "idle"):
                connection.execute(
                    text(
                        "INSERT INTO paths (space_id, start, goal, points, length_m, "
                        "robot_radius_m, resolution_m, floor_plan, follow_status, "
                        "follow_heartbeat) VALUES (1, '[0, 0]', '[1, 1]', '[]', 1.4, 0.2, "
                        "0.05, 'rooms', :status, :beat)"
                    ),
                    {"status": status, "beat": beat if status == "running" else None},
                )
        command.upgrade(config, "head")
        engine.dispose()

        def leases(table: str, status: str) -> list[tuple]:
            with engine.connect() as connection:
                rows = connection.execute(
                    text(
                        f"SELECT {status}, lease_owner, lease_expires_at, heartbeat_at, attempts "
                        f"FROM {table} ORDER BY id"
                    )
                ).all()

            def aware(t):  # SQLite keeps UTC without its zone
                if isinstance(t, str):
                    t = datetime.fromisoformat(t)
                return t if t is None or t.tzinfo else t.replace(tzinfo=UTC)

            return [(r[0], r[1], aware(r[2]), aware(r[3]), r[4]) for r in rows]

        at = datetime.fromtimestamp(beat, UTC)
        assert leases("tasks", "status") == [
            ("running", "host:1:ab", at + timedelta(seconds=60), at, 1),
            ("succeeded", None, None, at, 1),
        ]
        assert leases("paths", "follow_status") == [
            ("running", None, at + timedelta(seconds=30), at, 1),
            ("idle", None, None, None, 0),
        ]

        command.downgrade(config, "0010_zones")
        engine.dispose()
        with engine.connect() as connection:
            tasks = connection.execute(text("SELECT owner, heartbeat FROM tasks ORDER BY id")).all()
            paths = connection.execute(text("SELECT follow_heartbeat FROM paths ORDER BY id")).all()
        assert [tuple(r) for r in tasks] == [("host:1:ab", beat), (None, beat)]
        assert [tuple(r) for r in paths] == [(beat,), (None,)]
    finally:
        engine.dispose()
