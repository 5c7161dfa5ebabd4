"""FastAPI application factory.

``create_app(settings)`` wires everything: the database (first-run admin account), the
node hub with its websocket endpoint ``/ws/node``, the REST routers under ``/api`` (all but
login require a login), the static console at ``/``, and — in the lifespan — the viser 3D
view on its own port. To add a resource: write ``app/api/routes/<name>.py`` with an
``APIRouter`` named ``router`` (it is discovered, see :func:`api_routers`); to add a
console page drop an HTML file into
``static/``; to add a 3D panel write a ``populate_*`` function in :mod:`app.viewer`.
"""

from __future__ import annotations

import importlib
import ipaddress
import logging
import pkgutil
import secrets
import sys
from collections.abc import AsyncIterator, Sequence
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import numpy as np
from fastapi import APIRouter, Depends, FastAPI, Request, WebSocket
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles
from sqlalchemy.exc import OperationalError

import app.api.routes as routes_pkg
from app.api.deps import get_current_user
from app.api.hardening import BASE_HEADERS, SecurityMiddleware
from app.api.routes import auth
from app.api.routes._exporting import ExportGuard
from app.api.security import LoginThrottle, ensure_admin, password_problem
from app.config import DEFAULT_NODE_TOKEN, Settings, get_settings
from app.db.base import make_engine, make_session_factory
from app.server.hub import Hub
from app.server.registry import NodeSession
from app.viewer import proxy as viewer_proxy
from app.viewer.scene import SensorView
from engine.errors import CalibrationError, GaitrigError, InputError

log = logging.getLogger("gaitrig.server")

STATIC_DIR = Path(__file__).resolve().parents[1] / "static"

def api_routers() -> list[APIRouter]:
    """Every ``router`` in ``app/api/routes/`` except login, mounted under ``/api``.

    Each declares its own prefix and requires a login; discovery lets a resource be added
    without editing this file.
    """
    routers: list[APIRouter] = []
    for info in sorted(pkgutil.iter_modules(routes_pkg.__path__), key=lambda i: i.name):
        if info.name == "auth" or info.name.startswith("_"):
            continue
        try:
            module = importlib.import_module(f"{routes_pkg.__name__}.{info.name}")
        except ImportError:
            # A broken optional resource must not take the node link and recording down.
            log.exception("API resource %s could not be loaded and is disabled", info.name)
            continue
        router = getattr(module, "router", None)
        if isinstance(router, APIRouter):
            routers.append(router)
    return routers


def _sensor_views(hub: Hub) -> list[SensorView]:
    views = []
    for s in sorted(hub.registry.nodes.values(), key=lambda s: s.id):
        if s.sensor.T_world_sensor is not None:
            views.append(SensorView(s.id, np.asarray(s.sensor.T_world_sensor), s.sensor.fov_deg,
                                    s.connected))
    return views


def validation_message(errors: Sequence[Any]) -> str:
    """Pydantic's validation errors as one line a person can act on: the field's own name
    ("frames: Input should be greater than or equal to 2"), not its place in the request
    ("body.frames: …"); a missing or unreadable body is called that."""
    where = {"body": "the request body", "query": "the query", "path": "the address",
             "header": "a header", "cookie": "a cookie"}
    msgs = []
    for e in errors:
        if e.get("type") == "json_invalid":  # its loc is a character position
            msgs.append("the request body: is not valid JSON")
            continue
        loc = [str(x) for x in e.get("loc", ())]
        field = ".".join(loc[1:]) if loc and loc[0] in where else ".".join(loc)
        name = field or (where.get(loc[0], "the request") if loc else "the request")
        msgs.append(f"{name}: {e.get('msg', 'invalid')}")
    return "; ".join(msgs) or "the request is not valid"


def _loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return host == "localhost"


def deployment_problems(settings: Settings) -> list[str]:
    """Why these settings must not serve the clinic network (empty: none).

    A server on a loopback address serves one workstation (a demo, a developer, tests);
    one on any other interface is reachable from the network, and then the shipped node
    pairing token (public in the docs) and a weak first-run admin password are refused.
    """
    if _loopback(settings.host):
        return []
    problems = []
    if settings.node_token == DEFAULT_NODE_TOKEN:
        problems.append("the node pairing token is the shipped 'change-me-node-token', which "
                        "anyone who read the docs knows: set GAITRIG_NODE_TOKEN (server and "
                        "nodes) to a secret of your own, e.g. the output of "
                        "`python -c 'import secrets; print(secrets.token_urlsafe(24))'`")
    if settings.admin_password:
        why = password_problem(settings.admin_password, settings.admin_user)
        if why:
            problems.append(f"GAITRIG_ADMIN_PASSWORD is too weak ({why}); unset it to have a "
                            "strong one generated and printed at the first start")
    return problems


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the server app (nothing starts until the ASGI server runs the lifespan).

    Raises:
        InputError: the server would listen beyond this machine with settings that are
            unsafe there (see :func:`deployment_problems`).
    """
    settings = settings or get_settings()
    problems = deployment_problems(settings)
    if problems:
        raise InputError(f"refusing to serve {settings.host}:{settings.port} to the network: "
                         + "; ".join(problems))
    settings.data_dir.mkdir(parents=True, exist_ok=True)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        engine = make_engine(settings.db_url)
        app.state.db_sessions = make_session_factory(engine)
        with app.state.db_sessions() as db:
            generated = ensure_admin(db, settings.admin_user, settings.admin_password,
                                     settings.password_hash_cost)
        if generated:
            print(f"gaitrig: created console account {settings.admin_user!r} with password "
                  f"{generated!r} (change it after logging in)", file=sys.stderr, flush=True)
        if settings.node_token == DEFAULT_NODE_TOKEN:
            print("gaitrig: WARNING: nodes pair with the shipped token 'change-me-node-token'; "
                  "set GAITRIG_NODE_TOKEN (server and nodes) to a secret of your own",
                  file=sys.stderr, flush=True)
        hub = app.state.hub
        # The active calibration replaces the poses nodes report, now and on reconnect.
        from app.server.calibration import apply_to_registry

        apply_to_registry(hub.registry, settings.data_dir)
        viewer = None
        if settings.viewer_enabled:
            from app.viewer.active_area import ActiveAreaLayer
            from app.viewer.scene import Viewer, populate_sensors, populate_skeleton

            viewer = Viewer(settings.viewer_host, settings.viewer_port)
            # every sensor's active area (seed 004), kept current as nodes come and go
            app.state.active_areas = ActiveAreaLayer(viewer.server, hub)

            def redraw(_s: NodeSession) -> None:
                try:
                    populate_sensors(viewer.server, _sensor_views(hub))
                except Exception:  # the 3D view must never take the node link down
                    log.exception("could not update the 3D view")

            hub.registry.listeners.append(redraw)
            last_draw: dict[str, float] = {}

            def draw_skeleton(s: NodeSession) -> None:
                # ≤ 10 Hz per sensor: enough to watch, cheap for six sensors at 30 Hz
                sk = s.skeleton
                if sk is None or sk.t_local - last_draw.get(s.id, -1e9) < 0.1:
                    return
                if not viewer.server.get_clients():
                    # nobody looks: viser would still encode and queue every update (with
                    # the fused skeleton, a sixth of an idle server's CPU). Not counted as
                    # drawn, so a browser that connects gets the next frame (≤ 1/30 s).
                    return
                last_draw[s.id] = sk.t_local
                try:
                    populate_skeleton(viewer.server, s.id, sk.positions, sk.states)
                except Exception:
                    log.exception("could not draw the skeleton of %s", s.id)

            hub.skeleton_listeners.append(draw_skeleton)
        app.state.viewer = viewer
        try:
            yield
        finally:
            await hub.close()
            if viewer is not None:
                viewer.stop()
            engine.dispose()

    app = FastAPI(
        title="gaitrig",
        summary="Multi-depth-camera motion capture and gait lab",
        lifespan=lifespan,
    )
    app.state.settings = settings
    app.state.hub = Hub(settings)
    app.state.exports = ExportGuard()  # this app's own: apps in one process never share it
    app.state.login_throttle = LoginThrottle(settings.login_max_failures,
                                             settings.login_lockout_s)
    app.state.viewer = None

    api = APIRouter(prefix="/api")
    api.include_router(auth.router)
    for r in api_routers():
        # enforced here, so a new resource cannot forget it
        api.include_router(r, dependencies=[Depends(get_current_user)])
    app.include_router(api)
    # the 3D view behind the console's login (viser itself has none)
    app.include_router(viewer_proxy.router)

    @app.websocket("/ws/node")
    async def node_socket(ws: WebSocket) -> None:
        await app.state.hub.handle_node(ws)

    @app.get("/healthz", include_in_schema=False)
    def healthz() -> dict[str, str]:
        return {"status": "ok"}

    @app.exception_handler(GaitrigError)
    async def gaitrig_error(_req: Request, exc: GaitrigError) -> JSONResponse:
        if isinstance(exc, CalibrationError):
            # The request was understood but the observations cannot calibrate the rig.
            return JSONResponse({"detail": str(exc), "unreachable": exc.unreachable},
                                status_code=422)
        return JSONResponse({"detail": str(exc)}, status_code=400)

    @app.exception_handler(Exception)
    async def internal_error(request: Request, exc: Exception) -> JSONResponse:
        # A bug, not the user's input: the log gets the traceback under a reference the
        # person can quote; the answer names no file, query or library internals.
        ref = secrets.token_hex(4)
        log.error("internal error %s on %s %s", ref, request.method, request.url.path,
                  exc_info=exc)
        return JSONResponse({"detail": f"internal error (reference {ref}): the request "
                                       "could not be completed; the server log has the "
                                       "details under this reference"}, status_code=500,
                            headers={"cache-control": "no-store", **BASE_HEADERS})

    @app.exception_handler(OperationalError)
    async def database_unavailable(request: Request, exc: OperationalError) -> JSONResponse:
        # The database refused (SQLite locked by a long backup or another writer, disk
        # full, PostgreSQL unreachable): not a bug of the request, and the transaction was
        # rolled back, so the person may simply try again. The cause stays in the log.
        ref = secrets.token_hex(4)
        log.error("database unavailable %s on %s %s", ref, request.method,
                  request.url.path, exc_info=exc)
        return JSONResponse({"detail": f"the database is busy or cannot write at the moment "
                                       f"(reference {ref}); nothing was changed. Try again "
                                       "in a minute; if it keeps happening, check the "
                                       "server's free disk space and its log"},
                            status_code=503,
                            headers={"retry-after": "30", "cache-control": "no-store",
                                     **BASE_HEADERS})

    @app.exception_handler(RequestValidationError)
    async def validation_error(_req: Request, exc: RequestValidationError) -> JSONResponse:
        return JSONResponse({"detail": validation_message(exc.errors())}, status_code=422)

    @app.get("/", include_in_schema=False)
    def root() -> RedirectResponse:
        return RedirectResponse("/rig.html")

    if STATIC_DIR.is_dir():
        app.mount("/", StaticFiles(directory=STATIC_DIR, html=True), name="static")
    # outermost: cross-site requests are refused before anything runs; every answer (the
    # static console and error pages included) carries the security headers
    app.add_middleware(SecurityMiddleware, allowed_origins=settings.allowed_origins,
                       static_dir=STATIC_DIR)
    return app
