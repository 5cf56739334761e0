"""`intspace db upgrade|downgrade|current`: the registry's schema migrations."""

from __future__ import annotations

import argparse

from alembic import command

from server.db.migrate import alembic_config, backup_sqlite, schema_state, upgrade_to_head
from server.db.session import make_engine
from server.settings import Settings


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `db` command and its sub-commands."""
    parser = subparsers.add_parser("db", help="Database schema migrations.")
    sub = parser.add_subparsers(dest="db_command", metavar="ACTION", required=True)
    up = sub.add_parser("upgrade", help="Apply pending migrations (SQLite file backed up first).")
    up.set_defaults(func=_upgrade)
    down = sub.add_parser("downgrade", help="Revert to a revision (e.g. -1, base).")
    down.add_argument("revision")
    down.set_defaults(func=_downgrade)
    current = sub.add_parser("current", help="Print the current and head revisions.")
    current.set_defaults(func=_current)


def _upgrade(args: argparse.Namespace) -> int:
    settings = Settings()
    engine = make_engine(settings.resolved_database_url, pool_size=1)
    try:
        backup = upgrade_to_head(engine, settings.resolved_database_url)
        state = schema_state(engine, settings.resolved_database_url)
    finally:
        engine.dispose()
    if backup is not None:
        print(f"Backup: {backup}")
    print(f"Database at revision {state.current} (head {state.head})")
    return 0


def _downgrade(args: argparse.Namespace) -> int:
    settings = Settings()
    url = settings.resolved_database_url
    if settings.database_backend == "sqlite":
        backup = backup_sqlite(url, f"before-downgrade-{args.revision}")
        if backup is not None:
            print(f"Backup: {backup}")
    command.downgrade(alembic_config(url), args.revision)
    return _current(args)


def _current(args: argparse.Namespace) -> int:
    settings = Settings()
    engine = make_engine(settings.resolved_database_url, pool_size=1)
    try:
        state = schema_state(engine, settings.resolved_database_url)
    finally:
        engine.dispose()
    print(f"current: {state.current or '(none)'}")
    print(f"head: {state.head}")
    return 0 if not state.pending else 1
