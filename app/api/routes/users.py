"""Console accounts, for administrators: one per person, so the audit trail names people.

* ``GET /api/users`` — the accounts (name, administrator or not, since when, last login,
  open logins, whether the password is still one someone else chose).
* ``POST /api/users`` — ``{"username", "password", "is_admin"}``: a new account; the
  password follows the policy of ``POST /api/auth/password``.
* ``POST /api/users/{username}/password`` — ``{"new_password"}``: set someone's password
  (they forgot it, or it leaked); every login of theirs ends.
* ``POST /api/users/{username}/delete`` — ``{"confirm": "<username>"}``: remove an account
  and end its logins. One's own account and the last administrator cannot be removed.

A password an administrator sets (new account, reset) is a temporary one: the console
asks its owner to change it (``must_change_password`` in ``GET /api/auth/me``) until they
do. Each change is in the audit trail (action ``account``); the trail keeps the entries of
a removed account under its name.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

from fastapi import APIRouter, HTTPException, Request, status
from pydantic import BaseModel, Field
from sqlalchemy import func, select

from app.api import security
from app.api.deps import CurrentUser, DbDep, SettingsDep
from app.api.limits import BoundedRoute
from app.api.timestamps import as_utc, utc_iso
from app.db import audit
from app.db.models import AuditEvent, LoginSession, PasswordChangeDue, User

router = APIRouter(prefix="/users", route_class=BoundedRoute, tags=["users"])

#: What a user name may be: it is shown in the audit trail and typed at the login.
USERNAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.@-]{0,63}$"


class NewUser(BaseModel):
    username: str = Field(pattern=USERNAME_PATTERN,
                          description="Letters, digits, '_', '.', '@', '-' (e.g. a.nurse).")
    password: str = Field(min_length=1, max_length=256)
    is_admin: bool = False


class NewPassword(BaseModel):
    new_password: str = Field(min_length=1, max_length=256)


class Confirm(BaseModel):
    confirm: str = Field(max_length=64, description="The user name, typed again.")


def _admin(user: User) -> None:
    if not user.is_admin:
        raise HTTPException(status.HTTP_403_FORBIDDEN,
                            "only an administrator may manage accounts")


def _account(db: Any, username: str) -> User:
    found = db.scalar(select(User).where(User.username == username))
    if found is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no account named {username[:64]!r}")
    return found  # type: ignore[no-any-return]


def _policy(password: str, username: str) -> None:
    problem = security.password_problem(password, username)
    if problem:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, problem)


def mark_change_due(db: Any, user: User, reason: str) -> None:
    """Record that ``user``'s password was chosen by someone else (``generated`` or
    ``administrator``), so the console suggests changing it; not committed."""
    due = db.get(PasswordChangeDue, user.id)
    if due is None:
        db.add(PasswordChangeDue(user_id=user.id, reason=reason))
    else:
        due.reason, due.since = reason, datetime.now(UTC)


def change_due(db: Any, user: User) -> str | None:
    """Why ``user`` should change their password (who chose it), or None."""
    due = db.get(PasswordChangeDue, user.id)
    return None if due is None else str(due.reason)


def _client(request: Request) -> str:
    return request.client.host if request.client else ""


@router.get("")
def accounts(user: CurrentUser, db: DbDep) -> list[dict[str, Any]]:
    """Every account with its number of open logins (administrators only)."""
    _admin(user)
    open_logins: dict[int, int] = {
        uid: n for uid, n in db.execute(
            select(LoginSession.user_id, func.count(LoginSession.id))
            .where(LoginSession.expires_at > datetime.now(UTC))
            .group_by(LoginSession.user_id))}
    due = {d.user_id: d.reason for d in db.scalars(select(PasswordChangeDue))}
    # the last login from the audit trail, which keeps a removed account's entries under
    # its name: only a login since this account was created counts
    last: dict[str, datetime] = {
        name: as_utc(at) for name, at in db.execute(
            select(AuditEvent.username, func.max(AuditEvent.at))
            .where(AuditEvent.action == "login").group_by(AuditEvent.username))}
    out = []
    for u in db.scalars(select(User).order_by(User.username)):
        created = as_utc(u.created_at)
        seen = last.get(u.username)
        out.append({"username": u.username, "is_admin": u.is_admin,
                    "created_at": utc_iso(created),
                    "last_login_at": utc_iso(seen) if seen and seen >= created else None,
                    "open_logins": open_logins.get(u.id, 0),
                    "must_change_password": u.id in due, "password_set_by": due.get(u.id)})
    return out


@router.post("", status_code=201)
def create_account(body: NewUser, request: Request, user: CurrentUser, db: DbDep,
                   settings: SettingsDep) -> dict[str, Any]:
    """A new account (administrators only)."""
    _admin(user)
    if db.scalar(select(User.id).where(func.lower(User.username) == body.username.lower())):
        raise HTTPException(status.HTTP_409_CONFLICT,
                            f"an account named {body.username!r} exists already")
    _policy(body.password, body.username)
    new = User(username=body.username, password_hash=security.hash_password(
                   body.password, settings.password_hash_cost),
               is_admin=body.is_admin)
    db.add(new)
    db.flush()
    mark_change_due(db, new, "administrator")
    db.add(audit.event(user.username, "account", f"user {body.username}",
                       "created" + (" (administrator)" if body.is_admin else ""),
                       _client(request)))
    db.commit()
    return {"username": body.username, "is_admin": body.is_admin}


@router.post("/{username}/password", status_code=204)
def set_password(username: str, body: NewPassword, request: Request, user: CurrentUser,
                 db: DbDep, settings: SettingsDep) -> None:
    """Set an account's password and end its logins (administrators only; one's own:
    ``POST /api/auth/password``, which asks for the current one)."""
    _admin(user)
    target = _account(db, username)
    if target.id == user.id:
        raise HTTPException(status.HTTP_409_CONFLICT, "change your own password with POST "
                            "/api/auth/password (it asks for the current one)")
    _policy(body.new_password, target.username)
    mark_change_due(db, target, "administrator")  # committed with the new password
    ended = security.change_password(db, target, body.new_password, None,
                                    settings.password_hash_cost)
    logins = "1 login" if ended == 1 else f"{ended} logins"
    audit.record(db, user.username, "account", f"user {target.username}",
                 f"password set by an administrator; {logins} ended", _client(request))


@router.post("/{username}/delete")
def delete_account(username: str, body: Confirm, request: Request, user: CurrentUser,
                   db: DbDep) -> dict[str, Any]:
    """Remove an account and end its logins (administrators only)."""
    _admin(user)
    target = _account(db, username)
    if body.confirm != target.username:
        raise HTTPException(status.HTTP_400_BAD_REQUEST,
                            f"type the user name {target.username!r} to confirm")
    if target.id == user.id:
        raise HTTPException(status.HTTP_409_CONFLICT, "you cannot remove your own account")
    if target.is_admin and (db.scalar(select(func.count(User.id)).where(User.is_admin)) or 0) <= 1:
        raise HTTPException(status.HTTP_409_CONFLICT, "the last administrator cannot be removed")
    db.delete(target)
    db.add(audit.event(user.username, "account", f"user {target.username}", "removed",
                       _client(request)))
    db.commit()
    return {"deleted": "user", "username": target.username}
