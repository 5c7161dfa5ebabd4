"""The 3D view behind the console's login: ``/viewer/`` on the API port.

The viser server listens on its own port, on the loopback interface by default, and has
no login of its own. The console reaches it through this proxy instead: the page at
``GET /viewer/`` and its websocket at ``/viewer`` (the viser client connects to the page's
own URL) are forwarded to the viser server only for a logged-in session (the console's
session cookie, or a bearer token). So the live skeletons and depth images of a subject
are never served to someone who has not logged in, and the view works wherever the console
does (another machine, a container) without opening a second port.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from typing import Any

import websockets
from fastapi import APIRouter, HTTPException, Request, Response, WebSocket, status
from fastapi.responses import HTMLResponse
from starlette.requests import HTTPConnection
from starlette.websockets import WebSocketDisconnect

from app.api.deps import request_token, until_logged_out
from app.api.security import user_for_token

log = logging.getLogger(__name__)

#: Response headers of the viser page passed on to the browser.
_PASSED_HEADERS = ("content-type", "content-encoding", "cache-control", "etag", "last-modified")
#: Largest viser message forwarded (point clouds of six sensors fit well within it).
MAX_MESSAGE_BYTES = 64 * 1024 * 1024
#: Messages from viser held for one browser before the proxy stops reading from viser.
UPSTREAM_QUEUE = 4
#: A browser that takes no message for this long is dropped (close code 1013).
SEND_STALL_S = 20.0
#: How long closing waits for the other side (browser or viser) to take the close frame.
CLOSE_TIMEOUT_S = 5.0

router = APIRouter(prefix="/viewer", tags=["viewer"])


def _viewer_port(app: Any) -> int:
    viewer = getattr(app.state, "viewer", None)
    if viewer is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            "the 3D view is off on this server (started with --no-viewer)")
    return int(viewer.port)


_LOGIN_PAGE = """<!doctype html><html lang="en"><head><meta charset="utf-8">
<title>gaitrig — 3D view</title><link rel="stylesheet" href="/style.css"></head>
<body><main><h1>3D view</h1><p>You are not logged in. <a href="/index.html">Log in to the
console</a>, then open the 3D view from its Live page.</p></main></body></html>"""


def _session_user(request: HTTPConnection) -> Any:
    token = request_token(request)
    if not token:
        return None
    with request.app.state.db_sessions() as db:
        return user_for_token(db, token)


@router.get("/", include_in_schema=False)
@router.get("/{path:path}", include_in_schema=False)
async def viewer_page(request: Request, path: str = "") -> Response:
    """The viser client (one page with its assets) for a logged-in user."""
    if _session_user(request) is None:
        if "text/html" in request.headers.get("accept", ""):
            # a person's browser (a bookmark, a new tab): a page that says how to log in
            return HTMLResponse(_LOGIN_PAGE, status_code=status.HTTP_401_UNAUTHORIZED)
        raise HTTPException(status.HTTP_401_UNAUTHORIZED,
                            "not logged in: POST /api/auth/login with your username and "
                            "password", headers={"WWW-Authenticate": "Bearer"})
    port = _viewer_port(request.app)
    if ".." in path.split("/"):
        raise HTTPException(status.HTTP_404_NOT_FOUND, "no such file of the 3D view")
    # here, not at the top: httpx loads its command line's libraries (click, rich,
    # pygments), ~0.1 s of every server's start for a page asked for now and then
    import httpx

    headers = {"accept-encoding": request.headers.get("accept-encoding", "identity")}
    try:
        async with (httpx.AsyncClient(timeout=10.0) as client,
                    client.stream("GET", f"http://127.0.0.1:{port}/{path}",
                                  headers=headers) as r):
            # the bytes as viser sent them (compressed or not), its encoding header passed on
            body = b"".join([chunk async for chunk in r.aiter_raw()])
    except httpx.HTTPError as e:
        raise HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE,
                            f"the 3D view is not answering ({type(e).__name__}); "
                            "restart the server if this lasts") from None
    passed = {k: v for k, v in r.headers.items() if k.lower() in _PASSED_HEADERS}
    return Response(content=body, status_code=r.status_code, headers=passed)


async def _close_browser(ws: WebSocket, code: int = 1000, reason: str = "") -> None:
    """Close the browser's side, waiting at most ``CLOSE_TIMEOUT_S`` for it to take the
    close frame (a browser that reads nothing never does; the server then drops the
    connection when the handler returns)."""
    with contextlib.suppress(RuntimeError, WebSocketDisconnect, TimeoutError, OSError):
        async with asyncio.timeout(CLOSE_TIMEOUT_S):
            await ws.close(code=code, reason=reason)


@router.websocket("")
async def viewer_socket(ws: WebSocket) -> None:
    """The viser websocket, forwarded both ways for a logged-in session only.

    Backpressure, not buffering: each side is read only once the previous message went
    out on the other, so a browser that falls behind slows the viser server's stream to
    it (viser keeps the newest state of each scene node and drops stale updates) instead
    of growing this process's memory: at most ``UPSTREAM_QUEUE`` messages wait here, plus
    the socket buffers. A browser that takes nothing for ``SEND_STALL_S`` is dropped
    (close code 1013, try again later) so it does not hold a viser stream open forever.
    """
    viewer = getattr(ws.app.state, "viewer", None)
    if _session_user(ws) is None:
        await ws.close(code=4401, reason="not logged in")  # as the console's other sockets
        return
    if viewer is None:
        await ws.close(code=1008, reason="the 3D view is off on this server")
        return
    protocols = [p.strip() for p in ws.headers.get("sec-websocket-protocol", "").split(",")
                 if p.strip()]
    try:
        # compression=None: viser's messages are zstd + raw float arrays already;
        # deflating them again only costs CPU and latency on both ends
        upstream = await websockets.connect(
            f"ws://127.0.0.1:{viewer.port}", subprotocols=protocols or None,  # type: ignore[arg-type]
            max_size=MAX_MESSAGE_BYTES, max_queue=UPSTREAM_QUEUE, open_timeout=10,
            close_timeout=CLOSE_TIMEOUT_S, compression=None)
    except (OSError, websockets.WebSocketException, TimeoutError):
        log.warning("3D view proxy: the viser server is not answering")
        await ws.close(code=1011, reason="the 3D view is not answering; reload the page")
        return
    await ws.accept(subprotocol=upstream.subprotocol)
    stalled = False

    async def to_viewer() -> None:
        while True:
            msg = await ws.receive()
            if msg["type"] == "websocket.disconnect":
                return
            data = msg.get("bytes")
            await upstream.send(data if data is not None else msg.get("text") or "")

    async def to_browser() -> None:
        nonlocal stalled
        # the ASGI send itself: one dict per message, no further wrapping or copy
        send = ws.send
        async for data in upstream:
            key = "bytes" if isinstance(data, bytes) else "text"
            try:
                async with asyncio.timeout(SEND_STALL_S):
                    await send({"type": "websocket.send", key: data})
            except TimeoutError:
                stalled = True
                return

    # the login is checked again while the view is open: a logout ends it
    logged_out = asyncio.create_task(until_logged_out(ws, request_token(ws) or ""))
    tasks = [asyncio.create_task(to_viewer()), asyncio.create_task(to_browser()), logged_out]
    try:
        await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for t in tasks:
            t.cancel()
        for t in tasks:
            with contextlib.suppress(asyncio.CancelledError, WebSocketDisconnect,
                                     websockets.WebSocketException, RuntimeError, OSError):
                await t
        # viser first: its stream to this client stops at once, whatever the browser does
        if stalled:
            # what viser has queued for this browser is stale: no closing handshake behind it
            upstream.transport.abort()
        with contextlib.suppress(websockets.WebSocketException, OSError):
            await upstream.close()
        if stalled:
            log.warning("3D view proxy: a browser took nothing for %g s; dropped it",
                        SEND_STALL_S)
            await _close_browser(ws, 1013, f"the 3D view stalled: this browser took no data "
                                           f"for {SEND_STALL_S:g} s; reload the page")
        elif logged_out.done() and not logged_out.cancelled():
            await _close_browser(ws, 4401, "the login ended; log in again")
        else:
            await _close_browser(ws)
