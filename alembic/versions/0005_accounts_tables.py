"""Account tables: users, their login sessions, passwords someone else chose.

Revision ID: 0005
Revises: 0003
Create Date: 2026-11-25

Until this revision ``users``, ``login_sessions`` and ``password_change_due`` were made by
``create_all`` when the server opened its database, which adds a missing table but never
changes one: a later column would have needed a migration anyway. From here on alembic
owns them. The tables are written out here (not taken from the models), as the models'
``create_all`` made them; a table that already exists (every database of an earlier
release) is left as it is, so an existing database is adopted with its accounts.
"""

from __future__ import annotations

import sqlalchemy as sa

from alembic import op

revision = "0005"
down_revision = "0003"
branch_labels = None
depends_on = None

def _tz() -> sa.DateTime:
    return sa.DateTime(timezone=True)


def upgrade() -> None:
    existing = set(sa.inspect(op.get_bind()).get_table_names())
    if "users" not in existing:
        op.create_table(
            "users",
            sa.Column("id", sa.Integer, primary_key=True),
            sa.Column("username", sa.String(64), nullable=False),
            sa.Column("password_hash", sa.String(256), nullable=False),
            sa.Column("is_admin", sa.Boolean, nullable=False),
            sa.Column("created_at", _tz(), nullable=False),
        )
        op.create_index("ix_users_username", "users", ["username"], unique=True)
    if "login_sessions" not in existing:
        op.create_table(
            "login_sessions",
            sa.Column("id", sa.Integer, primary_key=True),
            sa.Column("token_sha256", sa.String(64), nullable=False),
            sa.Column("user_id", sa.Integer, sa.ForeignKey("users.id", ondelete="CASCADE"),
                      nullable=False),
            sa.Column("created_at", _tz(), nullable=False),
            sa.Column("expires_at", _tz(), nullable=False),
        )
        op.create_index("ix_login_sessions_token_sha256", "login_sessions", ["token_sha256"],
                        unique=True)
    if "password_change_due" not in existing:
        op.create_table(
            "password_change_due",
            sa.Column("user_id", sa.Integer, sa.ForeignKey("users.id", ondelete="CASCADE"),
                      primary_key=True),
            sa.Column("reason", sa.String(16), nullable=False),
            sa.Column("since", _tz(), nullable=False),
        )


def downgrade() -> None:
    # The tables stay: a release before this revision makes them with create_all when
    # they are missing and uses them when they are there, so keeping them keeps its
    # accounts (dropping them would lock everyone out of the downgraded server).
    pass
