"""Data tables: projects, subjects, sessions, recordings, recording parts, references.

Revision ID: 0001
Revises:
Create Date: 2026-11-22

The tables are written out here (not taken from the models) so that later model changes
need their own revision. Tables that already exist (a database made by ``create_all`` of
an earlier build) are left as they are.
"""

from __future__ import annotations

import sqlalchemy as sa

from alembic import op

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None


def _tz() -> sa.DateTime:
    return sa.DateTime(timezone=True)


def upgrade() -> None:
    existing = set(sa.inspect(op.get_bind()).get_table_names())
    if "projects" not in existing:
        op.create_table(
            "projects",
            sa.Column("id", sa.Integer, primary_key=True),
            sa.Column("name", sa.String(120), nullable=False, unique=True),
            sa.Column("description", sa.Text, nullable=False),
            sa.Column("created_at", _tz(), nullable=False),
        )
    if "subjects" not in existing:
        op.create_table(
            "subjects",
            sa.Column("id", sa.Integer, primary_key=True),
            sa.Column("project_id", sa.Integer,
                      sa.ForeignKey("projects.id", ondelete="CASCADE"), nullable=False,
                      index=True),
            sa.Column("code", sa.String(40), nullable=False),
            sa.Column("height_m", sa.Float, nullable=True),
            sa.Column("leg_length_m", sa.Float, nullable=True),
            sa.Column("sex", sa.String(10), nullable=False),
            sa.Column("birth_year", sa.Integer, nullable=True),
            sa.Column("notes", sa.Text, nullable=False),
            sa.Column("created_at", _tz(), nullable=False),
            sa.UniqueConstraint("project_id", "code", name="uq_subject_code"),
        )
    if "sessions" not in existing:
        op.create_table(
            "sessions",
            sa.Column("id", sa.Integer, primary_key=True),
            sa.Column("subject_id", sa.Integer,
                      sa.ForeignKey("subjects.id", ondelete="CASCADE"), nullable=False,
                      index=True),
            sa.Column("date", sa.Date, nullable=False),
            sa.Column("label", sa.String(120), nullable=False),
            sa.Column("notes", sa.Text, nullable=False),
            sa.Column("created_at", _tz(), nullable=False),
        )
    if "recordings" not in existing:
        op.create_table(
            "recordings",
            sa.Column("id", sa.String(64), primary_key=True),
            sa.Column("session_id", sa.Integer,
                      sa.ForeignKey("sessions.id", ondelete="CASCADE"), nullable=False,
                      index=True),
            sa.Column("label", sa.String(120), nullable=False),
            sa.Column("notes", sa.Text, nullable=False),
            sa.Column("state", sa.String(16), nullable=False),
            sa.Column("reason", sa.Text, nullable=True),
            sa.Column("t_start", sa.Float, nullable=True),
            sa.Column("t_stop", sa.Float, nullable=True),
            sa.Column("streams", sa.String(120), nullable=False),
            sa.Column("created_at", _tz(), nullable=False),
        )
    if "recording_parts" not in existing:
        op.create_table(
            "recording_parts",
            sa.Column("id", sa.Integer, primary_key=True),
            sa.Column("recording_id", sa.String(64),
                      sa.ForeignKey("recordings.id", ondelete="CASCADE"), nullable=False,
                      index=True),
            sa.Column("node_id", sa.String(64), nullable=False),
            sa.Column("state", sa.String(16), nullable=False),
            sa.Column("reason", sa.Text, nullable=True),
            sa.Column("n_frames", sa.Integer, nullable=False),
            sa.Column("bytes_total", sa.BigInteger, nullable=False),
            sa.Column("bytes_done", sa.BigInteger, nullable=False),
            sa.Column("manifest_sha256", sa.String(64), nullable=True),
            sa.Column("attempts", sa.Integer, nullable=False),
            sa.Column("updated_at", _tz(), nullable=False),
            sa.UniqueConstraint("recording_id", "node_id", name="uq_part_node"),
        )
    if "reference_imports" not in existing:
        op.create_table(
            "reference_imports",
            sa.Column("id", sa.Integer, primary_key=True),
            sa.Column("recording_id", sa.String(64),
                      sa.ForeignKey("recordings.id", ondelete="CASCADE"), nullable=False,
                      index=True),
            sa.Column("filename", sa.String(255), nullable=False),
            sa.Column("format", sa.String(8), nullable=False),
            sa.Column("stored_name", sa.String(80), nullable=False),
            sa.Column("size", sa.BigInteger, nullable=False),
            sa.Column("rate_hz", sa.Float, nullable=False),
            sa.Column("n_frames", sa.Integer, nullable=False),
            sa.Column("labels_json", sa.Text, nullable=False),
            sa.Column("created_at", _tz(), nullable=False),
        )


def downgrade() -> None:
    for name in ("reference_imports", "recording_parts", "recordings", "sessions", "subjects",
                 "projects"):
        op.drop_table(name)
