"""Server facts the console needs: where the 3D view is, version, clock limits."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request

from app.api.deps import CurrentUser, DbDep, SettingsDep
from app.api.limits import BoundedRoute
from app.api.timestamps import utc_iso_or_none
from app.config import DEFAULT_NODE_TOKEN

router = APIRouter(prefix="/system", route_class=BoundedRoute, tags=["system"])


@router.get("")
def system(request: Request, user: CurrentUser, settings: SettingsDep, db: DbDep
           ) -> dict[str, Any]:
    """Viewer URL (the login-protected proxy on this port), clock warning limit, version;
    for an administrator also the time of the last successful backup (``last_backup_at``,
    ISO 8601 UTC, null when there has been none; ``gaitrig backup``)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        ver = version("gaitrig")
    except PackageNotFoundError:
        ver = "dev"
    viewer = getattr(request.app.state, "viewer", None)
    out: dict[str, Any] = {
        "version": ver,
        "viewer_url": "/viewer/" if viewer is not None else None,
        "clock_warn_ms": settings.clock_warn_ms,
        "user": user.username,
        # the console warns an administrator while nodes pair with the shipped token
        "node_token_is_default": settings.node_token == DEFAULT_NODE_TOKEN,
    }
    if user.is_admin:  # the console reminds administrators when backups stop
        from app.server.backup import last_backup

        at = last_backup(db)
        out["last_backup_at"] = utc_iso_or_none(at, "seconds")
    return out
