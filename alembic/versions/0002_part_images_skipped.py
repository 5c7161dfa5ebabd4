"""recording_parts.images_skipped: frames of a part recorded without their images.

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-24

Stored when the part arrives on the server (the data sync reads it once from the server
copy's ``meta.json``); ``NULL`` for parts that arrived before this revision, for which the
recordings API reads ``meta.json`` as before. A table already holding the column (made by
``create_all`` of a build with this model) is left as it is.
"""

from __future__ import annotations

import sqlalchemy as sa

from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def _columns() -> set[str]:
    return {c["name"] for c in sa.inspect(op.get_bind()).get_columns("recording_parts")}


def upgrade() -> None:
    if "images_skipped" not in _columns():
        op.add_column("recording_parts",
                      sa.Column("images_skipped", sa.Integer, nullable=True))


def downgrade() -> None:
    if "images_skipped" in _columns():
        with op.batch_alter_table("recording_parts") as batch:
            batch.drop_column("images_skipped")
