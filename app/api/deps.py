"""Shared FastAPI dependencies as ``Annotated`` aliases.

Use them in a route's signature::

    @router.get("/things")
    def things(user: CurrentUser, hub: HubDep, settings: SettingsDep) -> list[Thing]: ...

``CurrentUser`` makes a route require a login (bearer token or the console's session
cookie); every ``/api`` router except login is mounted with it (see
:func:`app.main.create_app`).
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from typing import Annotated, Any

from fastapi import Depends, HTTPException, Request, status
from fastapi.concurrency import run_in_threadpool
from sqlalchemy.orm import Session
from starlette.requests import HTTPConnection

from app.api.routes._exporting import ExportGuard
from app.api.security import user_for_token
from app.config import Settings
from app.db.models import User
from app.server.hub import Hub
from app.server.registry import NodeRegistry

SESSION_COOKIE = "gaitrig_session"


def get_app_settings(request: Request) -> Settings:
    """The settings the app was created with."""
    settings: Settings = request.app.state.settings
    return settings


def get_hub(request: Request) -> Hub:
    """The node hub (registry + recordings)."""
    hub: Hub = request.app.state.hub
    return hub


def get_db(request: Request) -> Iterator[Session]:
    """A database session for one request."""
    factory: Any = request.app.state.db_sessions
    with factory() as db:
        yield db


def get_registry(request: Request) -> NodeRegistry:
    """The node registry (health, clocks, latest data of every node)."""
    return get_hub(request).registry


def get_exports(request: Request) -> ExportGuard:
    """The app's guard of subject exports against deletions (``app.state.exports``)."""
    guard: ExportGuard = request.app.state.exports
    return guard


SettingsDep = Annotated[Settings, Depends(get_app_settings)]
HubDep = Annotated[Hub, Depends(get_hub)]
RegistryDep = Annotated[NodeRegistry, Depends(get_registry)]
DbDep = Annotated[Session, Depends(get_db)]
ExportsDep = Annotated[ExportGuard, Depends(get_exports)]


def request_token(request: HTTPConnection) -> str | None:
    """Bearer token from the Authorization header, else the session cookie (HTTP or websocket)."""
    auth = request.headers.get("authorization", "")
    if auth.lower().startswith("bearer "):
        return auth[7:].strip() or None
    return request.cookies.get(SESSION_COOKIE)


def get_current_user(request: Request, db: DbDep) -> User:
    """The logged-in user, or HTTP 401 saying how to log in."""
    token = request_token(request)
    settings: Settings = request.app.state.settings
    # this request is activity: the login's idle timeout starts over
    user = user_for_token(db, token, settings.session_idle_minutes * 60,
                          settings.session_hours * 3600) if token else None
    if user is None:
        raise HTTPException(
            status.HTTP_401_UNAUTHORIZED,
            detail="not logged in (or the login expired or was idle too long): POST "
                   "/api/auth/login with your username and password",
            headers={"WWW-Authenticate": "Bearer"},
        )
    return user


CurrentUser = Annotated[User, Depends(get_current_user)]

#: How often an open console websocket (Live panels, 3D view) re-checks its login.
SOCKET_LOGIN_CHECK_S = 5.0


def _login_valid(conn: HTTPConnection, token: str) -> bool:
    with conn.app.state.db_sessions() as db:
        return user_for_token(db, token) is not None


async def until_logged_out(conn: HTTPConnection, token: str) -> None:
    """Return once the login ``token`` has ended (logout, expiry, idle timeout, a password
    change or reset), checked every :data:`SOCKET_LOGIN_CHECK_S`.

    A websocket is authenticated once, at its handshake; without this, a stream of a
    subject's images would outlive the logout of the person who opened it. Waiting on a
    socket does not count as activity for the idle timeout.
    """
    while True:
        await asyncio.sleep(SOCKET_LOGIN_CHECK_S)
        if not await run_in_threadpool(_login_valid, conn, token):
            return
