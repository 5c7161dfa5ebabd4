"""Console login: ``POST /api/auth/login``, ``POST /api/auth/logout``, ``GET /api/auth/me``,
``POST /api/auth/password`` (change one's own password).

The session cookie is ``HttpOnly``, ``SameSite=Strict`` and ``Secure`` whenever the request
came over HTTPS (through a reverse proxy: ``X-Forwarded-Proto`` from a proxy uvicorn trusts,
see ``GAITRIG_FORWARDED_ALLOW_IPS``) or ``GAITRIG_COOKIE_SECURE`` is set. Every login
mints a new random token (a token the browser already held is never promoted, so there is
no session fixation); a logout ends the token on the server.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from fastapi import APIRouter, HTTPException, Request, Response, status
from pydantic import BaseModel, Field

from app.api import security
from app.api.deps import (
    SESSION_COOKIE,
    CurrentUser,
    DbDep,
    SettingsDep,
    get_current_user,
    request_token,
)
from app.api.limits import BoundedRoute
from app.config import Settings
from app.db import audit
from app.db.models import PasswordChangeDue

router = APIRouter(prefix="/auth", route_class=BoundedRoute, tags=["auth"])


class LoginIn(BaseModel):
    username: str = Field(min_length=1, max_length=64)
    password: str = Field(min_length=1, max_length=256)


class LoginOut(BaseModel):
    token: str
    expires_at: datetime
    username: str


class PasswordIn(BaseModel):
    current_password: str = Field(min_length=1, max_length=256)
    new_password: str = Field(min_length=1, max_length=256)


class PasswordChanged(BaseModel):
    """What a password change did besides setting the password."""

    #: How many other logins of this user (other browsers, computers) were ended.
    other_sessions_ended: int


class UserOut(BaseModel):
    username: str
    is_admin: bool
    #: The password is one someone else chose (generated at the first start, or set by an
    #: administrator): the console suggests changing it.
    must_change_password: bool = False
    #: Who chose it: ``generated`` or ``administrator`` (None once the owner changed it).
    password_set_by: str | None = None


@router.post("/login", response_model=LoginOut)
def login(body: LoginIn, request: Request, response: Response, db: DbDep,
          settings: SettingsDep) -> LoginOut:
    """Log in; returns a bearer token and sets the console's session cookie.

    After ``login_max_failures`` wrong passwords for one user name from one address within
    ``login_lockout_s``, that address is told to wait (HTTP 429, ``Retry-After``).
    """
    throttle: security.LoginThrottle = request.app.state.login_throttle
    client = request.client.host if request.client else "?"
    wait = throttle.retry_after(body.username, client)
    if wait > 0:
        minutes = max(1, round(wait / 60))
        raise HTTPException(status.HTTP_429_TOO_MANY_REQUESTS,
                            f"too many wrong passwords for {body.username!r}; try again in "
                            f"{minutes} min or ask the administrator to reset the password",
                            headers={"Retry-After": str(int(wait) + 1)})
    got = security.login(db, body.username, body.password, settings.session_hours,
                         settings.session_idle_minutes * 60, settings.password_hash_cost)
    if got is None:
        paused = throttle.failed(body.username, client)
        audit.record_failed_login(
            db, body.username, client,
            note=f"further logins paused for {settings.login_lockout_s:g} s" if paused else "")
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "wrong username or password")
    throttle.succeeded(body.username, client)
    audit.record(db, body.username, "login", client=client)
    token, expires = got
    response.set_cookie(SESSION_COOKIE, token, httponly=True, samesite="strict",
                        secure=cookie_secure(request, settings),
                        max_age=int(settings.session_hours * 3600))
    return LoginOut(token=token, expires_at=expires, username=body.username)


def cookie_secure(request: Request, settings: Settings) -> bool:
    """Whether the session cookie is sent over HTTPS only: ``settings.cookie_secure`` when
    set, else whether this request came over HTTPS."""
    if settings.cookie_secure is not None:
        return settings.cookie_secure
    return request.url.scheme == "https"


@router.post("/logout", status_code=204)
def logout(request: Request, response: Response, user: CurrentUser, db: DbDep) -> None:
    """End this login."""
    token = request_token(request)
    if token:
        security.logout(db, token)
    audit.record(db, user.username, "logout",
                 client=request.client.host if request.client else "")
    response.delete_cookie(SESSION_COOKIE, httponly=True, samesite="strict",
                           secure=cookie_secure(request, request.app.state.settings))


@router.post("/password", response_model=PasswordChanged)
def change_password(body: PasswordIn, request: Request, user: CurrentUser, db: DbDep,
                    settings: SettingsDep) -> PasswordChanged:
    """Change one's own password (``{"current_password", "new_password"}``).

    The new one must have at least 12 characters and not contain the user name. Every
    other login of this user ends (a stolen session does not survive the change); wrong
    current passwords count as failed logins (throttled, audited). Answers 200 with
    ``{"other_sessions_ended": n}`` so the console can say how many logins it ended (it
    was a bodiless 204; a client that only checks for success keeps working).
    """
    throttle: security.LoginThrottle = request.app.state.login_throttle
    client = request.client.host if request.client else "?"
    wait = throttle.retry_after(user.username, client)
    if wait > 0:
        raise HTTPException(status.HTTP_429_TOO_MANY_REQUESTS,
                            f"too many wrong passwords; try again in {max(1, round(wait / 60))} "
                            "min", headers={"Retry-After": str(int(wait) + 1)})
    if not security.verify_password(body.current_password, user.password_hash):
        paused = throttle.failed(user.username, client)
        audit.record_failed_login(
            db, user.username, client,
            note="wrong current password at a password change"
            + (f"; paused for {settings.login_lockout_s:g} s" if paused else ""))
        raise HTTPException(status.HTTP_403_FORBIDDEN, "the current password is wrong")
    problem = security.password_problem(body.new_password, user.username)
    if problem is None and body.new_password == body.current_password:
        problem = "the new password must differ from the current one"
    if problem:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, problem)
    due = db.get(PasswordChangeDue, user.id)
    if due is not None:  # the password is now the owner's own (committed with it)
        db.delete(due)
    ended = security.change_password(db, user, body.new_password, request_token(request),
                                    settings.password_hash_cost)
    audit.record(db, user.username, "password_change",
                 detail=f"{ended} other login{'' if ended == 1 else 's'} ended", client=client)
    return PasswordChanged(other_sessions_ended=ended)


def _user_out(user: Any, db: Any) -> UserOut:
    due = db.get(PasswordChangeDue, user.id)
    return UserOut(username=user.username, is_admin=user.is_admin,
                   must_change_password=due is not None,
                   password_set_by=None if due is None else due.reason)


@router.get("/me", response_model=UserOut)
def me(user: CurrentUser, db: DbDep) -> UserOut:
    """Who is logged in, and whether their password is still one someone else chose."""
    return _user_out(user, db)


class SessionOut(BaseModel):
    logged_in: bool
    user: UserOut | None = None


@router.get("/session", response_model=SessionOut)
def session(request: Request, db: DbDep) -> SessionOut:
    """Whether anyone is logged in, answered 200 either way.

    Pages open without a login (the Help page) ask this to offer "Log in" or the user
    menu; ``/me`` answers 401 to nobody, which a browser logs as a failed request.
    """
    try:
        user = get_current_user(request, db)
    except HTTPException:
        return SessionOut(logged_in=False)
    return SessionOut(logged_in=True, user=_user_out(user, db))
