"""semantic objects, navigation places and edges (the landmark maps)

Revision ID: 0006
Revises: 0005
Create Date: 2026-11-24 03:30:00.000000
"""

from collections.abc import Sequence
from typing import Any

import sqlalchemy as sa
from alembic import op

revision: str = "0006"
down_revision: str | None = "0005"
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


def _space(table: str) -> list[Any]:
    return [
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("space_id", sa.Integer(), nullable=False),
        sa.ForeignKeyConstraint(
            ["space_id"],
            ["spaces.id"],
            name=op.f(f"fk_{table}_space_id_spaces"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f(f"pk_{table}")),
    ]


def upgrade() -> None:
    op.create_table(
        "semantic_objects",
        *_space("semantic_objects"),
        sa.Column("mark_id", sa.Integer(), nullable=False),
        sa.Column("object_class", sa.String(length=200), nullable=False),
        sa.Column("name", sa.String(length=200), nullable=False),
        sa.Column("room", sa.String(length=200), nullable=False),
        sa.Column("T_world_mark", sa.JSON(), nullable=False),
        sa.Column("cov", sa.JSON(), nullable=False),
        sa.Column("last_seen", sa.Float(), nullable=False),
        sa.Column("reads", sa.Integer(), nullable=False),
        sa.Column("confidence", sa.Float(), nullable=False),
        sa.Column("payload", sa.Text(), nullable=False),
        *_timestamps(),
        sa.UniqueConstraint("space_id", "mark_id", name=op.f("uq_semantic_objects_space_id")),
    )
    op.create_table(
        "navigation_places",
        *_space("navigation_places"),
        sa.Column("mark_id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=200), nullable=False),
        sa.Column("room", sa.String(length=200), nullable=False),
        sa.Column("pose", sa.JSON(), nullable=False),
        sa.Column("neighbours", sa.JSON(), nullable=False),
        sa.Column("last_seen", sa.Float(), nullable=False),
        sa.Column("reads", sa.Integer(), nullable=False),
        sa.Column("payload", sa.Text(), nullable=False),
        *_timestamps(),
        sa.UniqueConstraint("space_id", "mark_id", name=op.f("uq_navigation_places_space_id")),
    )
    op.create_table(
        "navigation_edges",
        *_space("navigation_edges"),
        sa.Column("from_mark", sa.Integer(), nullable=False),
        sa.Column("to_mark", sa.Integer(), nullable=False),
        sa.Column("length_m", sa.Float(), nullable=False),
        sa.Column("via", sa.String(length=20), nullable=False),
        *_timestamps(),
        sa.UniqueConstraint(
            "space_id", "from_mark", "to_mark", name=op.f("uq_navigation_edges_space_id")
        ),
    )
    for table in ("semantic_objects", "navigation_places", "navigation_edges"):
        with op.batch_alter_table(table, schema=None) as batch_op:
            batch_op.create_index(batch_op.f(f"ix_{table}_space_id"), ["space_id"], unique=False)


def downgrade() -> None:
    for table in ("navigation_edges", "navigation_places", "semantic_objects"):
        with op.batch_alter_table(table, schema=None) as batch_op:
            batch_op.drop_index(batch_op.f(f"ix_{table}_space_id"))
        op.drop_table(table)
