"""calibration run leases, attempts and progress

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-24 01:50:00.000000
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0004"
down_revision: str | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("calibration_runs", schema=None) as batch_op:
        batch_op.add_column(sa.Column("attempts", sa.Integer(), server_default="0", nullable=False))
        batch_op.add_column(sa.Column("lease_owner", sa.String(length=120), nullable=True))
        batch_op.add_column(
            sa.Column("lease_expires_at", sa.DateTime(timezone=True), nullable=True)
        )
        batch_op.add_column(sa.Column("progress_stage", sa.String(length=80), nullable=True))
        batch_op.add_column(sa.Column("progress_fraction", sa.Float(), nullable=True))
    # Every run started before leases existed was claimed once; one left running has no lease,
    # so it counts as expired and the first worker to look re-queues it.
    op.execute("UPDATE calibration_runs SET attempts = 1 WHERE started_at IS NOT NULL")


def downgrade() -> None:
    with op.batch_alter_table("calibration_runs", schema=None) as batch_op:
        batch_op.drop_column("progress_fraction")
        batch_op.drop_column("progress_stage")
        batch_op.drop_column("lease_expires_at")
        batch_op.drop_column("lease_owner")
        batch_op.drop_column("attempts")
