"""paths (planned paths, projector trajectories, follow tasks); projector calibrations

Revision ID: 0007
Revises: 0006
Create Date: 2026-11-24 04:40:00.000000
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0007"
down_revision: str | None = "0006"
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
    op.create_table(
        "paths",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("space_id", sa.Integer(), nullable=False),
        sa.Column("projector_id", sa.Integer(), nullable=True),
        sa.Column("start", sa.JSON(), nullable=False),
        sa.Column("goal", sa.JSON(), nullable=False),
        sa.Column("points", sa.JSON(), nullable=False),
        sa.Column("length_m", sa.Float(), nullable=False),
        sa.Column("robot_radius_m", sa.Float(), nullable=False),
        sa.Column("resolution_m", sa.Float(), nullable=False),
        sa.Column("floor_plan", sa.String(length=200), nullable=False),
        sa.Column("spot_speed_mps", sa.Float(), nullable=True),
        sa.Column("projector_model", sa.JSON(), nullable=True),
        sa.Column("trajectory", sa.JSON(), nullable=True),
        sa.Column("follow_status", sa.String(length=20), nullable=False),
        sa.Column("follow_law", sa.String(length=40), nullable=True),
        sa.Column("follow_seed", sa.Integer(), nullable=True),
        sa.Column("follow_progress", sa.Float(), nullable=True),
        sa.Column("follow_heartbeat", sa.Float(), nullable=True),
        sa.Column("follow_result", sa.JSON(), nullable=True),
        sa.Column("follow_series", sa.JSON(), nullable=True),
        sa.Column("follow_error", sa.Text(), nullable=True),
        sa.Column("follow_started_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("follow_finished_at", sa.DateTime(timezone=True), nullable=True),
        *_timestamps(),
        sa.ForeignKeyConstraint(
            ["space_id"], ["spaces.id"], name=op.f("fk_paths_space_id_spaces"), ondelete="CASCADE"
        ),
        sa.ForeignKeyConstraint(
            ["projector_id"],
            ["projectors.id"],
            name=op.f("fk_paths_projector_id_projectors"),
            ondelete="SET NULL",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_paths")),
    )
    with op.batch_alter_table("paths", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_paths_space_id"), ["space_id"], unique=False)
    op.create_table(
        "projector_calibrations",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("projector_id", sa.Integer(), nullable=False),
        sa.Column("calibration_run_id", sa.Integer(), nullable=True),
        sa.Column("T_world_projector", sa.JSON(), nullable=False),
        sa.Column("tilt_offset", sa.Float(), nullable=False),
        sa.Column("rms_m", sa.Float(), nullable=False),
        sa.Column("spots", sa.Integer(), nullable=False),
        *_timestamps(),
        sa.ForeignKeyConstraint(
            ["projector_id"],
            ["projectors.id"],
            name=op.f("fk_projector_calibrations_projector_id_projectors"),
            ondelete="CASCADE",
        ),
        sa.ForeignKeyConstraint(
            ["calibration_run_id"],
            ["calibration_runs.id"],
            name=op.f("fk_projector_calibrations_calibration_run_id_calibration_runs"),
            ondelete="SET NULL",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_projector_calibrations")),
    )
    with op.batch_alter_table("projector_calibrations", schema=None) as batch_op:
        batch_op.create_index(
            batch_op.f("ix_projector_calibrations_projector_id"), ["projector_id"], unique=False
        )


def downgrade() -> None:
    with op.batch_alter_table("projector_calibrations", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_projector_calibrations_projector_id"))
    op.drop_table("projector_calibrations")
    with op.batch_alter_table("paths", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_paths_space_id"))
    op.drop_table("paths")
