"""Fixtures shared by the whole suite: where the repository and its shared data are, and fresh
PostgreSQL databases when INTSPACE_TEST_POSTGRES_URL names a server."""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
POSTGRES_ENV = "INTSPACE_TEST_POSTGRES_URL"


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """Return the repository's root directory."""
    return REPO_ROOT


@pytest.fixture(scope="session")
def shared_data_dir() -> Path:
    """Return <repo>/../shared/data (published data sets used as ground truth), or the folder
    INTSPACE_TEST_SHARED_DATA names (a checkout that is not beside `shared`)."""
    named = os.environ.get("INTSPACE_TEST_SHARED_DATA")
    return Path(named) if named else REPO_ROOT.parent / "shared" / "data"


def _postgres_unavailable(reason: str) -> None:
    # In CI the PostgreSQL half of the suite is required: a missing server is a failure.
    if os.environ.get("CI", "").lower() == "true":
        pytest.fail(f"{reason} (CI=true requires PostgreSQL)")
    pytest.skip(reason)


@pytest.fixture(scope="session")
def postgres_server_url() -> str:
    """Return the PostgreSQL URL of INTSPACE_TEST_POSTGRES_URL after checking it answers; skip
    when unset (fail instead under CI=true)."""
    url = os.environ.get(POSTGRES_ENV)
    if not url:
        _postgres_unavailable(f"{POSTGRES_ENV} is not set")
    from sqlalchemy import create_engine, text

    engine = create_engine(url, pool_pre_ping=True)
    try:
        with engine.connect() as connection:
            connection.execute(text("SELECT 1"))
    except Exception as exc:
        _postgres_unavailable(f"PostgreSQL at {POSTGRES_ENV} is unreachable: {exc}")
    finally:
        engine.dispose()
    return url


@pytest.fixture(scope="session")
def make_postgres_database(postgres_server_url: str) -> Iterator[Callable[[], str]]:
    """Return a factory of fresh, uniquely named, empty PostgreSQL databases (URLs); all are
    dropped at the end of the session."""
    from sqlalchemy import create_engine, text
    from sqlalchemy.engine import make_url

    server = make_url(postgres_server_url)
    admin = create_engine(server, isolation_level="AUTOCOMMIT")
    created: list[str] = []

    def make() -> str:
        name = f"intspace_t_{uuid.uuid4().hex[:12]}"
        with admin.connect() as connection:
            connection.execute(text(f'CREATE DATABASE "{name}"'))
        created.append(name)
        return server.set(database=name).render_as_string(hide_password=False)

    yield make
    with admin.connect() as connection:
        for name in created:
            connection.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
    admin.dispose()
