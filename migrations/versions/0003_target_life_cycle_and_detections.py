"""target life cycle, detections

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-23 23:40:00.000000
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: str | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def _timestamps() -> list[sa.Column]:
    return [
        sa.Column(
            name,
            sa.DateTime(timezone=True),
            server_default=sa.text("(CURRENT_TIMESTAMP)"),
            nullable=False,
        )
        for name in ("created_at", "updated_at")
    ]


def upgrade() -> None:
    with op.batch_alter_table("targets", schema=None) as batch_op:
        # Targets from before the tracker had a life cycle are history.
        batch_op.add_column(
            sa.Column("state", sa.String(length=20), nullable=False, server_default="ended")
        )
        batch_op.add_column(sa.Column("track_id", sa.Integer(), nullable=True))
        batch_op.add_column(sa.Column("first_seen", sa.Float(), nullable=True))
        batch_op.add_column(sa.Column("last_seen", sa.Float(), nullable=True))
        batch_op.create_index(batch_op.f("ix_targets_state"), ["state"], unique=False)
        batch_op.create_index(batch_op.f("ix_targets_last_seen"), ["last_seen"], unique=False)
    with op.batch_alter_table("targets", schema=None) as batch_op:
        batch_op.alter_column("state", server_default=None)
    op.execute("UPDATE targets SET kind = 'unknown' WHERE kind = 'external'")
    with op.batch_alter_table("track_points", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_track_points_t"), ["t"], unique=False)

    op.create_table(
        "detections",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("space_id", sa.Integer(), nullable=True),
        sa.Column("camera_id", sa.Integer(), nullable=False),
        sa.Column("t", sa.Float(), nullable=False),
        sa.Column("u", sa.Float(), nullable=False),
        sa.Column("v", sa.Float(), nullable=False),
        sa.Column("cxx", sa.Float(), nullable=False),
        sa.Column("cxy", sa.Float(), nullable=False),
        sa.Column("cyy", sa.Float(), nullable=False),
        sa.Column("kind", sa.String(length=20), nullable=False),
        sa.Column("height", sa.Float(), nullable=False),
        sa.Column("label", sa.String(length=200), nullable=True),
        *_timestamps(),
        sa.ForeignKeyConstraint(
            ["space_id"],
            ["spaces.id"],
            name=op.f("fk_detections_space_id_spaces"),
            ondelete="CASCADE",
        ),
        sa.ForeignKeyConstraint(
            ["camera_id"],
            ["cameras.id"],
            name=op.f("fk_detections_camera_id_cameras"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_detections")),
    )
    with op.batch_alter_table("detections", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_detections_space_id"), ["space_id"], unique=False)
        batch_op.create_index(batch_op.f("ix_detections_t"), ["t"], unique=False)


def downgrade() -> None:
    with op.batch_alter_table("detections", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_detections_t"))
        batch_op.drop_index(batch_op.f("ix_detections_space_id"))
    op.drop_table("detections")
    with op.batch_alter_table("track_points", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_track_points_t"))
    op.execute("UPDATE targets SET kind = 'external' WHERE kind = 'unknown'")
    with op.batch_alter_table("targets", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_targets_last_seen"))
        batch_op.drop_index(batch_op.f("ix_targets_state"))
        batch_op.drop_column("last_seen")
        batch_op.drop_column("first_seen")
        batch_op.drop_column("track_id")
        batch_op.drop_column("state")
