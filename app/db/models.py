"""Tables: console users, their login sessions and the audit trail.

Kept deliberately small; the data-management models (projects, subjects, sessions,
recordings) are added beside these, deriving from :class:`app.db.base.Base`.
"""

from __future__ import annotations

from datetime import UTC, datetime

from sqlalchemy import DDL, Boolean, DateTime, ForeignKey, Integer, String, Text, event
from sqlalchemy.orm import Mapped, mapped_column, relationship

from app.db.base import Base


def _now() -> datetime:
    return datetime.now(UTC)


class User(Base):
    """A console account. ``password_hash`` is an scrypt string (see :mod:`app.api.security`)."""

    __tablename__ = "users"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    username: Mapped[str] = mapped_column(String(64), unique=True, index=True)
    password_hash: Mapped[str] = mapped_column(String(256))
    is_admin: Mapped[bool] = mapped_column(Boolean, default=False)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=_now)

    sessions: Mapped[list[LoginSession]] = relationship(
        back_populates="user", cascade="all, delete-orphan")


class LoginSession(Base):
    """A console login; the client holds the token, the table only its SHA-256."""

    __tablename__ = "login_sessions"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    token_sha256: Mapped[str] = mapped_column(String(64), unique=True, index=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"))
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=_now)
    expires_at: Mapped[datetime] = mapped_column(DateTime(timezone=True))

    user: Mapped[User] = relationship(back_populates="sessions")


class PasswordChangeDue(Base):
    """An account whose password someone else chose: generated at the first start or set
    by an administrator (a new account, a reset). The console suggests changing it; the
    owner's own change (``POST /api/auth/password``) removes the row.

    A table of its own rather than a column of ``users``: ``users`` was made by
    ``create_all`` (alembic owns it since revision 0005), which adds missing tables to an
    existing database but never columns.
    """

    __tablename__ = "password_change_due"

    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"),
                                         primary_key=True)
    #: Who chose the password: ``generated`` or ``administrator``.
    reason: Mapped[str] = mapped_column(String(16))
    since: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=_now)


#: The account tables, versioned by alembic (revision 0005 creates them when missing);
#: ``create_all`` makes only the tables in neither this nor :data:`app.db.data.DATA_TABLES`.
ACCOUNT_TABLES = ("users", "login_sessions", "password_change_due")

#: What the audit trail records (``AuditEvent.action``).
AUDIT_ACTIONS = ("login", "login_failed", "logout", "password_change", "account", "export",
                 "delete", "backup", "restore", "storage_check")


class AuditEvent(Base):
    """One entry of the append-only audit trail: who did what, when, from where.

    Targets name rows by their numeric id or a recording id, never by a subject code,
    so the trail keeps no trace of a deleted subject's pseudonym. The database refuses
    any UPDATE or DELETE of this table (triggers, SQLite and PostgreSQL), so an entry
    cannot be edited through the application's database connection.
    """

    __tablename__ = "audit_events"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=_now, index=True)
    username: Mapped[str] = mapped_column(String(64))
    action: Mapped[str] = mapped_column(String(16), index=True)
    target: Mapped[str] = mapped_column(String(200), default="")
    detail: Mapped[str] = mapped_column(Text, default="")
    client: Mapped[str] = mapped_column(String(64), default="")


for _op in ("UPDATE", "DELETE"):
    event.listen(AuditEvent.__table__, "after_create", DDL(
        f"CREATE TRIGGER audit_events_no_{_op.lower()} BEFORE {_op} ON audit_events "
        "BEGIN SELECT RAISE(ABORT, 'the audit trail is append-only'); END"
    ).execute_if(dialect="sqlite"))
event.listen(AuditEvent.__table__, "after_create", DDL(
    "CREATE OR REPLACE FUNCTION audit_events_append_only() RETURNS trigger AS $$ BEGIN "
    "RAISE EXCEPTION 'the audit trail is append-only'; END $$ LANGUAGE plpgsql"
).execute_if(dialect="postgresql"))
event.listen(AuditEvent.__table__, "after_create", DDL(
    "CREATE TRIGGER audit_events_no_change BEFORE UPDATE OR DELETE ON audit_events "
    "FOR EACH ROW EXECUTE FUNCTION audit_events_append_only()"
).execute_if(dialect="postgresql"))
