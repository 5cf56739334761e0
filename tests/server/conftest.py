"""Fixtures of the API tests: the real app on a real database, SQLite (a file per test) and,
when INTSPACE_TEST_POSTGRES_URL is set, PostgreSQL (a database per session, emptied per test)."""

from __future__ import annotations

import shutil
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import create_engine, text

from server.app import create_app
from server.db.base import Base
from server.db.migrate import alembic_config
from server.settings import Settings
from tests.support.waiting import wait_for_run as support_wait_for_run

ADMIN_TOKEN = "test-admin-token"
ADMIN = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
BACKENDS = ["sqlite", "postgresql"]


def _migrate(url: str) -> None:
    from alembic import command

    command.upgrade(alembic_config(url), "head")


@pytest.fixture(scope="session")
def sqlite_template(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Return a SQLite file migrated to head once; each test gets a copy (milliseconds)."""
    path = tmp_path_factory.mktemp("template") / "template.sqlite3"
    _migrate(f"sqlite:///{path}")
    return path


@pytest.fixture(scope="session")
def postgres_database(make_postgres_database: Callable[[], str]) -> str:
    """Return the URL of a PostgreSQL database migrated to head, shared by the session."""
    url = make_postgres_database()
    _migrate(url)
    return url


def _empty_postgres(url: str) -> None:
    tables = ", ".join(f'"{t.name}"' for t in Base.metadata.sorted_tables)
    engine = create_engine(url)
    try:
        with engine.begin() as connection:
            connection.execute(text(f"TRUNCATE {tables} RESTART IDENTITY CASCADE"))
    finally:
        engine.dispose()


@pytest.fixture(params=BACKENDS)
def database_url(request: pytest.FixtureRequest, tmp_path: Path, sqlite_template: Path) -> str:
    """Return the URL of an empty database at head: a fresh SQLite file, or the session's
    PostgreSQL database truncated."""
    if request.param == "sqlite":
        path = tmp_path / "intspace.sqlite3"
        shutil.copyfile(sqlite_template, path)
        return f"sqlite:///{path}"
    url = request.getfixturevalue("postgres_database")
    _empty_postgres(url)
    return url


@pytest.fixture
def make_settings(database_url: str, tmp_path: Path) -> Callable[..., Settings]:
    """Return a factory of settings on the test's database (scene off, known admin token)."""

    def make(**overrides: Any) -> Settings:
        values: dict[str, Any] = {
            "database_url": database_url,
            "data_dir": tmp_path,
            "admin_token": ADMIN_TOKEN,
            "viser_enabled": False,
            "run_workers": 2,
        }
        values.update(overrides)
        return Settings(_env_file=None, **values)

    return make


@pytest.fixture
def client(make_settings: Callable[..., Settings]) -> Iterator[TestClient]:
    """Return a client of the real app (lifespan run) on the test's database."""
    with TestClient(create_app(make_settings())) as test_client:
        yield test_client


def wait_for_run(client: TestClient, run_id: int, stalled_after_s: float = 60.0) -> dict[str, Any]:
    """Poll a calibration run until it leaves queued/running; return its JSON. It fails when
    the run's status, stage and fraction stay the same for `stalled_after_s` seconds, never
    at a total deadline (tests/support/waiting.py)."""

    def read() -> dict[str, Any]:
        response = client.get(f"/api/v1/calibration-runs/{run_id}", headers=ADMIN)
        assert response.status_code == 200, response.text
        return response.json()

    return support_wait_for_run(read, stalled_after_s=stalled_after_s, poll_s=0.05)


@pytest.fixture
def admin() -> dict[str, str]:
    """Return the headers authenticating as the configured admin."""
    return dict(ADMIN)


@pytest.fixture
def run_waiter() -> Callable[[TestClient, int], dict[str, Any]]:
    """Return wait_for_run(client, run_id) -> the finished run's JSON."""
    return wait_for_run
