"""Which `intspace serve` process holds an advisory lock of PostgreSQL (a space's tracker, the
home's availability topic), read from the database as an operator would."""

from __future__ import annotations

from typing import Any

from sqlalchemy import create_engine, text

from server.services.ownership import APPLICATION_NAME


def lock_holder(database_url: str, condition: str, params: dict[str, Any]) -> int | None:
    """Return the process id of the service holding the granted advisory lock that `condition`
    (SQL on pg_locks `l`, with `params`) selects, None when nobody holds it. A service names its
    connections APPLICATION_NAME:pid."""
    engine = create_engine(database_url)
    try:
        with engine.connect() as c:
            name = c.execute(
                text(
                    "SELECT a.application_name FROM pg_locks l JOIN pg_stat_activity a "
                    f"USING (pid) WHERE l.locktype = 'advisory' AND l.granted AND {condition}"
                ),
                params,
            ).scalar()
    finally:
        engine.dispose()
    if name is None:
        return None
    assert name.startswith(APPLICATION_NAME + ":")
    return int(name.split(":")[1])
