"""Live view: depth panels over a websocket, and the live stream statistics.

``WS /api/live/ws`` (session cookie required; closes with 4401 otherwise) streams each
node's newest depth panel as binary messages (see :mod:`app.server.streaming`); the page
acknowledges each drawn panel with ``{"type": "ack", "node": <its node>}`` (at most two
panels per node are in flight per page: a slow page skips frames instead of building a
backlog) and may send
``{"type": "time", "echo": <its clock>}`` and gets ``{"type": "time", "t":
<server clock>, "echo": ...}`` back, to convert capture times to its own clock.
``GET /api/live/status`` → requested rate, per-node panel rates, sent/dropped counters,
and the last coverage redraw times of the 3D view.

The router's lifespan starts the live services (:class:`app.viewer.live.LiveServices`)
after the app's own lifespan created the hub and the 3D view.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from fastapi import APIRouter, FastAPI, Request
from starlette.routing import WebSocketRoute
from starlette.websockets import WebSocket, WebSocketDisconnect

from app.api.deps import SESSION_COOKIE, CurrentUser, until_logged_out
from app.api.limits import BoundedRoute
from app.api.security import user_for_token
from app.server.streaming import Watcher
from app.viewer.live import LiveServices

MAX_CLIENT_MESSAGE = 4096


@asynccontextmanager
async def live_lifespan(app: FastAPI) -> AsyncIterator[None]:
    """Start the live services once the hub and the 3D view exist."""
    viewer = getattr(app.state, "viewer", None)
    services = LiveServices(app.state.hub, viewer.server if viewer is not None else None)
    app.state.live = services
    await services.start()
    try:
        yield
    finally:
        await services.stop()


router = APIRouter(prefix="/live", route_class=BoundedRoute, tags=["live"], lifespan=live_lifespan)


def services_of(app: Any) -> LiveServices:
    """The running live services (HTTP 503 if the server is still starting)."""
    s = getattr(app.state, "live", None)
    if s is None:
        from fastapi import HTTPException

        raise HTTPException(503, "the live services are starting; retry in a moment")
    live: LiveServices = s
    return live


@router.get("/status")
async def live_status(request: Request, user: CurrentUser) -> dict[str, Any]:
    """Live panel rates per node, watcher counters and 3D-view redraw times."""
    s = services_of(request.app)
    out = s.streams.stats()
    out["coverage_draw_ms"] = [round(v, 2) for v in s.coverage_draw_ms[-10:]]
    out["viewer"] = s.viewer is not None
    return out


async def live_socket(ws: WebSocket) -> None:
    """Depth panels for one browser; requires the console's session cookie."""
    token = ws.cookies.get(SESSION_COOKIE)
    user = None
    if token:
        with ws.app.state.db_sessions() as db:
            user = user_for_token(db, token)
    if user is None or token is None:
        await ws.close(code=4401, reason="not logged in")
        return
    services = getattr(ws.app.state, "live", None)
    if services is None:
        await ws.close(code=1013, reason="live services starting; retry")
        return
    await ws.accept()

    async def close_at_logout(token: str) -> None:
        await until_logged_out(ws, token)
        with contextlib.suppress(RuntimeError, WebSocketDisconnect):
            await ws.close(code=4401, reason="the login ended; log in again")

    guard = asyncio.get_running_loop().create_task(close_at_logout(token))
    watcher = Watcher(send=ws.send_bytes)
    await ws.send_text(json.dumps({"type": "hello", "t": time.time(),
                                   "fps": services.streams.fps}))
    services.streams.add_watcher(watcher)
    sender = asyncio.get_running_loop().create_task(watcher.run())
    try:
        while True:
            msg = await ws.receive()
            if msg["type"] == "websocket.disconnect":
                break
            text = msg.get("text")
            if not text or len(text) > MAX_CLIENT_MESSAGE:
                continue
            with contextlib.suppress(ValueError, TypeError, AttributeError):
                m = json.loads(text)
                if m.get("type") == "ack":
                    node = m.get("node")
                    watcher.ack(int(m.get("n", 1)), node if isinstance(node, str) else None)
                elif m.get("type") == "time":
                    await ws.send_text(json.dumps({"type": "time", "t": time.time(),
                                                   "echo": m.get("echo")}))
    except (WebSocketDisconnect, RuntimeError):
        pass
    finally:
        guard.cancel()
        services.streams.remove_watcher(watcher)
        sender.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await sender


# A plain Starlette route: the HTTP login dependency of /api routers cannot run on a
# websocket, so this endpoint checks the session cookie itself.
router.routes.append(WebSocketRoute("/live/ws", live_socket, name="live_ws"))
