"""one lease shape on every job table: calibration runs, tasks and paths' follow tasks

Revision ID: 0011_job_leases
Revises: 0010_zones
Create Date: 2026-11-27 17:30:00.000000

Tasks kept their process in `owner` and its last sign of life in `heartbeat` (Unix s, stale
after 60 s); paths kept `follow_heartbeat` (Unix s, stale after 30 s). Both now hold the
columns calibration runs have (lease_owner, lease_expires_at, attempts) and all three a
`heartbeat_at`; a live job's lease expires when its old heartbeat went stale.
"""

from collections.abc import Sequence
from datetime import UTC, datetime, timedelta
from typing import Any

import sqlalchemy as sa
from alembic import op

revision: str = "0011_job_leases"
down_revision: str | None = "0010_zones"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

# How long each kind's heartbeat took to go stale before leases (its new lease length).
_TASK_STALE_S = 60.0
_FOLLOW_STALE_S = 30.0


def _lease_columns() -> list[sa.Column]:
    return [
        sa.Column("lease_owner", sa.String(length=120), nullable=True),
        sa.Column("lease_expires_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("heartbeat_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("attempts", sa.Integer(), server_default="0", nullable=False),
    ]


def _job_table(name: str, status: str, heartbeat: str, owner: str | None) -> sa.TableClause:
    columns: list[sa.ColumnClause[Any]] = [
        sa.column("id", sa.Integer()),
        sa.column(status, sa.String()),
        sa.column(heartbeat, sa.Float()),
        sa.column("lease_owner", sa.String()),
        sa.column("lease_expires_at", sa.DateTime(timezone=True)),
        sa.column("heartbeat_at", sa.DateTime(timezone=True)),
        sa.column("attempts", sa.Integer()),
    ]
    if owner is not None:
        columns.append(sa.column(owner, sa.String()))
    return sa.table(name, *columns)


def _to_leases(
    name: str, status: str, heartbeat: str, owner: str | None, live: tuple[str, ...], stale_s: float
) -> None:
    """Move each row's Unix-seconds heartbeat (and owner) into the lease columns: a live row's
    lease expires when its heartbeat went stale; a row that ever ran was claimed once."""
    table = _job_table(name, status, heartbeat, owner)
    c = table.c
    bind = op.get_bind()
    selected = [c.id, c[status], c[heartbeat]] + ([c[owner]] if owner is not None else [])
    for row in bind.execute(sa.select(*selected)).all():
        beat = row[2]
        at = None if beat is None else datetime.fromtimestamp(float(beat), UTC)
        values = {
            "heartbeat_at": at,
            "lease_expires_at": (
                at + timedelta(seconds=stale_s) if at is not None and row[1] in live else None
            ),
            "lease_owner": row[3] if owner is not None and row[1] in live else None,
            "attempts": 0 if row[1] == "idle" else 1,
        }
        bind.execute(sa.update(table).where(c.id == row[0]).values(**values))


def _from_leases(name: str, status: str, heartbeat: str, owner: str | None) -> None:
    table = _job_table(name, status, heartbeat, owner)
    c = table.c
    bind = op.get_bind()
    for row in bind.execute(sa.select(c.id, c.heartbeat_at, c.lease_owner)).all():
        at = row[1]
        if at is not None and at.tzinfo is None:  # SQLite keeps UTC without its zone
            at = at.replace(tzinfo=UTC)
        values: dict[str, object] = {heartbeat: None if at is None else at.timestamp()}
        if owner is not None:
            values[owner] = row[2]
        bind.execute(sa.update(table).where(c.id == row[0]).values(**values))


def upgrade() -> None:
    with op.batch_alter_table("calibration_runs", schema=None) as batch_op:
        batch_op.add_column(sa.Column("heartbeat_at", sa.DateTime(timezone=True), nullable=True))
    for name in ("tasks", "paths"):
        with op.batch_alter_table(name, schema=None) as batch_op:
            for column in _lease_columns():
                batch_op.add_column(column)
    live_task = ("queued", "running")
    _to_leases("tasks", "status", "heartbeat", "owner", live_task, _TASK_STALE_S)
    _to_leases("paths", "follow_status", "follow_heartbeat", None, ("running",), _FOLLOW_STALE_S)
    with op.batch_alter_table("tasks", schema=None) as batch_op:
        batch_op.drop_column("heartbeat")
        batch_op.drop_column("owner")
    with op.batch_alter_table("paths", schema=None) as batch_op:
        batch_op.drop_column("follow_heartbeat")


def downgrade() -> None:
    with op.batch_alter_table("tasks", schema=None) as batch_op:
        batch_op.add_column(sa.Column("owner", sa.String(length=120), nullable=True))
        batch_op.add_column(sa.Column("heartbeat", sa.Float(), nullable=True))
    with op.batch_alter_table("paths", schema=None) as batch_op:
        batch_op.add_column(sa.Column("follow_heartbeat", sa.Float(), nullable=True))
    _from_leases("tasks", "status", "heartbeat", "owner")
    _from_leases("paths", "follow_status", "follow_heartbeat", None)
    for name in ("tasks", "paths"):
        with op.batch_alter_table(name, schema=None) as batch_op:
            for column in reversed(_lease_columns()):
                batch_op.drop_column(column.name)
    with op.batch_alter_table("calibration_runs", schema=None) as batch_op:
        batch_op.drop_column("heartbeat_at")
