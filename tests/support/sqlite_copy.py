"""A session factory on a test's own copy of the migrated SQLite template (a copy takes
milliseconds; migrating takes seconds)."""

from __future__ import annotations

import shutil
from pathlib import Path

from sqlalchemy import create_engine
from sqlalchemy.orm import Session, sessionmaker


def copied_database(template: Path, folder: Path) -> sessionmaker[Session]:
    """Return a session factory (objects kept readable after commit) on a copy of `template`
    written to `folder`/db.sqlite3."""
    path = folder / "db.sqlite3"
    shutil.copyfile(template, path)
    return sessionmaker(create_engine(f"sqlite:///{path}"), expire_on_commit=False)
