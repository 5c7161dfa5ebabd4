"""Server facts the console needs: where the 3D view is, version, clock limits."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request

from app.api.deps import CurrentUser, SettingsDep
from app.api.limits import BoundedRoute
from app.config import DEFAULT_NODE_TOKEN

router = APIRouter(prefix="/system", route_class=BoundedRoute, tags=["system"])


@router.get("")
def system(request: Request, user: CurrentUser, settings: SettingsDep) -> dict[str, Any]:
    """Viewer URL (same host name the browser used), clock warning limit, version."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        ver = version("gaitrig")
    except PackageNotFoundError:
        ver = "dev"
    viewer = getattr(request.app.state, "viewer", None)
    host = settings.public_host or request.url.hostname or "127.0.0.1"
    return {
        "version": ver,
        "viewer_url": f"http://{host}:{viewer.port}/" if viewer is not None else None,
        "clock_warn_ms": settings.clock_warn_ms,
        "user": user.username,
        # the console warns an administrator while nodes pair with the shipped token
        "node_token_is_default": settings.node_token == DEFAULT_NODE_TOKEN,
    }
