"""Indexes for the console's lists at clinic scale (thousands of subjects, tens of
thousands of recordings).

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-24

* ``recordings.state``: the data sync asks for the recordings not yet complete twice a
  second, and the reports list for those with data on the server;
* ``recordings.created_at``: recordings are listed newest first;
* ``subjects.code``: subjects of every project are listed and searched by code (within
  one project the unique ``(project_id, code)`` index serves).

An index that already exists (a database made by ``create_all`` of a build with these
models) is left as it is.
"""

from __future__ import annotations

import sqlalchemy as sa

from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None

INDEXES = (("ix_recordings_state", "recordings", ["state"]),
           ("ix_recordings_created_at", "recordings", ["created_at"]),
           ("ix_subjects_code", "subjects", ["code"]))


def _existing(table: str) -> set[str]:
    return {str(i["name"]) for i in sa.inspect(op.get_bind()).get_indexes(table)}


def upgrade() -> None:
    for name, table, cols in INDEXES:
        if name not in _existing(table):
            op.create_index(name, table, cols)


def downgrade() -> None:
    for name, table, _ in INDEXES:
        if name in _existing(table):
            op.drop_index(name, table_name=table)
