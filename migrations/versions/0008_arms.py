"""arms on robots, their hand-eye history, hand-eye runs' arm, and robot tasks

Revision ID: 0008
Revises: 0007
Create Date: 2026-11-24 05:00:00.000000
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0008"
down_revision: str | None = "0007"
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
        "arms",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("robot_id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=200), nullable=False),
        sa.Column("dh", sa.JSON(), nullable=False),
        sa.Column("limits", sa.JSON(), nullable=False),
        sa.Column("tool", sa.JSON(), nullable=False),
        sa.Column("home", sa.JSON(), nullable=False),
        sa.Column("T_robot_arm", sa.JSON(), nullable=False),
        sa.Column("camera_id", sa.Integer(), nullable=True),
        sa.Column("T_ee_camera", sa.JSON(), nullable=True),
        sa.Column("hand_eye_run_id", sa.Integer(), nullable=True),
        *_timestamps(),
        sa.ForeignKeyConstraint(
            ["robot_id"], ["robots.id"], name=op.f("fk_arms_robot_id_robots"), ondelete="CASCADE"
        ),
        sa.ForeignKeyConstraint(
            ["camera_id"],
            ["cameras.id"],
            name=op.f("fk_arms_camera_id_cameras"),
            ondelete="SET NULL",
        ),
        sa.ForeignKeyConstraint(
            ["hand_eye_run_id"],
            ["calibration_runs.id"],
            name=op.f("fk_arms_hand_eye_run_id_calibration_runs"),
            ondelete="SET NULL",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_arms")),
        sa.UniqueConstraint("robot_id", "name", name=op.f("uq_arms_robot_id")),
    )
    with op.batch_alter_table("arms", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_arms_robot_id"), ["robot_id"], unique=False)

    op.create_table(
        "hand_eye_calibrations",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("arm_id", sa.Integer(), nullable=False),
        sa.Column("calibration_run_id", sa.Integer(), nullable=True),
        sa.Column("T_ee_camera", sa.JSON(), nullable=False),
        sa.Column("rotation_std_deg", sa.Float(), nullable=False),
        sa.Column("translation_std_m", sa.Float(), nullable=False),
        sa.Column("rms_px", sa.Float(), nullable=True),
        sa.Column("method", sa.String(length=40), nullable=False),
        *_timestamps(),
        sa.ForeignKeyConstraint(
            ["arm_id"],
            ["arms.id"],
            name=op.f("fk_hand_eye_calibrations_arm_id_arms"),
            ondelete="CASCADE",
        ),
        sa.ForeignKeyConstraint(
            ["calibration_run_id"],
            ["calibration_runs.id"],
            name=op.f("fk_hand_eye_calibrations_calibration_run_id_calibration_runs"),
            ondelete="SET NULL",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_hand_eye_calibrations")),
    )
    with op.batch_alter_table("hand_eye_calibrations", schema=None) as batch_op:
        batch_op.create_index(
            batch_op.f("ix_hand_eye_calibrations_arm_id"), ["arm_id"], unique=False
        )

    with op.batch_alter_table("calibration_runs", schema=None) as batch_op:
        batch_op.add_column(sa.Column("arm_id", sa.Integer(), nullable=True))
        batch_op.create_index(batch_op.f("ix_calibration_runs_arm_id"), ["arm_id"], unique=False)
        batch_op.create_foreign_key(
            batch_op.f("fk_calibration_runs_arm_id_arms"),
            "arms",
            ["arm_id"],
            ["id"],
            ondelete="SET NULL",
        )

    op.create_table(
        "tasks",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("kind", sa.String(length=40), nullable=False),
        sa.Column("status", sa.String(length=20), nullable=False),
        sa.Column("arm_id", sa.Integer(), nullable=True),
        sa.Column("inputs", sa.JSON(), nullable=False),
        sa.Column("phase", sa.String(length=80), nullable=True),
        sa.Column("progress", sa.Float(), nullable=True),
        sa.Column("result", sa.JSON(), nullable=True),
        sa.Column("error", sa.Text(), nullable=True),
        sa.Column("owner", sa.String(length=120), nullable=True),
        sa.Column("heartbeat", sa.Float(), nullable=True),
        sa.Column("started_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("finished_at", sa.DateTime(timezone=True), nullable=True),
        *_timestamps(),
        sa.ForeignKeyConstraint(
            ["arm_id"], ["arms.id"], name=op.f("fk_tasks_arm_id_arms"), ondelete="SET NULL"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_tasks")),
    )
    with op.batch_alter_table("tasks", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_tasks_arm_id"), ["arm_id"], unique=False)
        batch_op.create_index(batch_op.f("ix_tasks_status"), ["status"], unique=False)


def downgrade() -> None:
    with op.batch_alter_table("tasks", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_tasks_status"))
        batch_op.drop_index(batch_op.f("ix_tasks_arm_id"))
    op.drop_table("tasks")
    with op.batch_alter_table("calibration_runs", schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f("fk_calibration_runs_arm_id_arms"), type_="foreignkey")
        batch_op.drop_index(batch_op.f("ix_calibration_runs_arm_id"))
        batch_op.drop_column("arm_id")
    with op.batch_alter_table("hand_eye_calibrations", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_hand_eye_calibrations_arm_id"))
    op.drop_table("hand_eye_calibrations")
    with op.batch_alter_table("arms", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_arms_robot_id"))
    op.drop_table("arms")
