"""Writing the audit trail (:class:`app.db.models.AuditEvent`).

Routes add an event to their own database session, so it is committed with the change it
records (a deletion and its entry are one transaction); :func:`record` commits it alone
for actions that change nothing else (a login, an export).
"""

from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.orm import Session

from app.db.models import AUDIT_ACTIONS, AuditEvent, User


def event(username: str, action: str, target: str = "", detail: str = "",
          client: str = "") -> AuditEvent:
    """A new audit entry (not yet added to a session).

    Raises:
        ValueError: ``action`` is not one of :data:`AUDIT_ACTIONS` (a programming error).
    """
    if action not in AUDIT_ACTIONS:
        raise ValueError(f"unknown audit action {action!r}")
    return AuditEvent(username=username[:64], action=action, target=target[:200],
                      detail=detail[:2000], client=client[:64])


def record(db: Session, username: str, action: str, target: str = "", detail: str = "",
           client: str = "") -> None:
    """Append one entry and commit it."""
    db.add(event(username, action, target, detail, client))
    db.commit()


def record_failed_login(db: Session, username: str, client: str, note: str = "") -> None:
    """Append a failed login (``note``: what followed, e.g. a pause). A name that is no
    account is not kept: people type their password into the user name field, and the
    trail must not hold it."""
    known = db.scalar(select(User.id).where(User.username == username)) is not None
    detail = "; ".join(x for x in ("" if known else "no account with the name given", note)
                       if x)
    record(db, username if known else "(unknown user)", "login_failed", detail=detail,
           client=client)
