"""Console login: ``POST /api/auth/login``, ``POST /api/auth/logout``, ``GET /api/auth/me``."""

from __future__ import annotations

from datetime import datetime

from fastapi import APIRouter, HTTPException, Request, Response, status
from pydantic import BaseModel, Field

from app.api import security
from app.api.deps import SESSION_COOKIE, CurrentUser, DbDep, SettingsDep, request_token
from app.api.limits import BoundedRoute
from app.db import audit

router = APIRouter(prefix="/auth", route_class=BoundedRoute, tags=["auth"])


class LoginIn(BaseModel):
    username: str = Field(min_length=1, max_length=64)
    password: str = Field(min_length=1, max_length=256)


class LoginOut(BaseModel):
    token: str
    expires_at: datetime
    username: str


class UserOut(BaseModel):
    username: str
    is_admin: bool


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
    got = security.login(db, body.username, body.password, settings.session_hours)
    if got is None:
        throttle.failed(body.username, client)
        audit.record_failed_login(db, body.username, client)
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "wrong username or password")
    throttle.succeeded(body.username, client)
    audit.record(db, body.username, "login", client=client)
    token, expires = got
    response.set_cookie(SESSION_COOKIE, token, httponly=True, samesite="strict",
                        max_age=int(settings.session_hours * 3600))
    return LoginOut(token=token, expires_at=expires, username=body.username)


@router.post("/logout", status_code=204)
def logout(request: Request, response: Response, user: CurrentUser, db: DbDep) -> None:
    """End this login."""
    token = request_token(request)
    if token:
        security.logout(db, token)
    audit.record(db, user.username, "logout",
                 client=request.client.host if request.client else "")
    response.delete_cookie(SESSION_COOKIE)


@router.get("/me", response_model=UserOut)
def me(user: CurrentUser) -> UserOut:
    """Who is logged in."""
    return UserOut(username=user.username, is_admin=user.is_admin)
