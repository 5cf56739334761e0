"""detections carry a detector's box, score and cut sides; cameras a score threshold

Revision ID: 0009_detection_boxes
Revises: 0008
Create Date: 2026-11-27 11:00:00.000000
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0009_detection_boxes"
down_revision: str | None = "0008"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("detections") as batch:
        batch.add_column(sa.Column("box", sa.JSON(), nullable=True))
        batch.add_column(sa.Column("score", sa.Float(), nullable=True))
        batch.add_column(sa.Column("cut", sa.JSON(), nullable=True))
    with op.batch_alter_table("cameras") as batch:
        batch.add_column(
            sa.Column("score_threshold", sa.Float(), server_default="0.5", nullable=False)
        )


def downgrade() -> None:
    with op.batch_alter_table("cameras") as batch:
        batch.drop_column("score_threshold")
    with op.batch_alter_table("detections") as batch:
        batch.drop_column("cut")
        batch.drop_column("score")
        batch.drop_column("box")
