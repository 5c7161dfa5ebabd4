"""KSCC page API: two skeleton sources, live calibration, comparison, two-site links,
active-area trapezoids.

* ``GET /api/kscc/sources`` — this server's nodes that can be a side.
* ``POST /api/kscc/session`` — start: ``{"a": source, "b": source, "countdown_s",
  "by_role"}``; a source is ``{"kind": "node", "node_id"}`` or ``{"kind": "remote",
  "url", "node_id", "token"}``.
* ``GET /api/kscc/session`` — ``"running": true`` with both sides (link, countdown,
  stillness progress, calibration, latest universal-frame skeleton) and the comparison
  (difference over time, similarity); with no session running (a normal state, which the
  page polls) 200 and ``"running": false`` with ``sides`` and ``comparison`` null.
* ``POST /api/kscc/session/restart`` ``{"side": "a"|"b"|"both"}``, ``DELETE
  /api/kscc/session``.
* ``GET/POST /api/kscc/shares``, ``DELETE /api/kscc/shares/{node_id}`` — share a node of
  this server with another site under a link token.
* ``WS /api/kscc/link`` — the other site's server connects here (token-authenticated, see
  :mod:`app.server.kscc_link`); it is the only route here without a console login.
* ``GET /api/kscc/active-area`` — per node: height, tilt and the trapezoid for the Kinect
  v1 / v2 / Azure presets; also drawn on the floor of the 3D view.
* ``GET /api/kscc/trapezoid?height_m=&tilt_deg=`` — the presets' trapezoids for any height.
"""

from __future__ import annotations

import logging
import re
from typing import Any, Literal

import numpy as np
from fastapi import APIRouter, HTTPException, Query, Request, status
from pydantic import BaseModel, Field
from starlette.websockets import WebSocket

from app.api.deps import CurrentUser, HubDep
from app.api.limits import BoundedRoute
from app.server.kscc_link import (
    MIN_TOKEN_LEN,
    KsccManager,
    KsccSession,
    PeerNotAllowedError,
    SourceSpec,
)
from app.viewer.active_area import (
    ActiveArea,
    model_key,
    node_area,
    pose_numbers,
)
from engine.coverage import (
    SENSOR_MODELS,
    Trapezoid,
    preset_trapezoid,
)
from engine.errors import InputError

log = logging.getLogger("gaitrig.kscc")

_NODE_RE = r"^[A-Za-z0-9_.-]{1,64}$"
PRESETS = {"kinect_v1": "Kinect v1", "kinect_v2": "Kinect v2", "azure_nfov": "Azure Kinect (NFOV)",
           "azure_wfov": "Azure Kinect (WFOV)"}


def manager(app: Any) -> KsccManager:
    """The app's KSCC manager, created on first use (also hooks the 3D view)."""
    m: KsccManager | None = getattr(app.state, "kscc", None)
    if m is None:
        viewer = getattr(app.state, "viewer", None)
        m = KsccManager(app.state.hub, _viewer_hook(viewer) if viewer is not None else None)
        app.state.kscc = m
    return m


router = APIRouter(prefix="/kscc", route_class=BoundedRoute, tags=["kscc"])

def _viewer_hook(viewer: Any) -> Any:
    from app.viewer.kscc import populate_kscc

    def draw(sess: KsccSession) -> None:
        items: dict[str, Any] = {}
        for k, side in sess.sides.items():
            if side.calibrated and side.history and side.joint_set is not None:
                _, U, st = side.history[-1]
                items[k] = (U, st, side.joint_set)
            else:
                items[k] = None
        populate_kscc(viewer.server, items, {k: s.source.label() for k, s in sess.sides.items()})

    return draw


class SourceIn(BaseModel):
    """One side's skeleton source."""

    kind: Literal["node", "remote"]
    node_id: str = Field(pattern=_NODE_RE)
    url: str | None = Field(default=None, max_length=300)
    token: str | None = Field(default=None, max_length=256)


class SessionIn(BaseModel):
    a: SourceIn
    b: SourceIn
    countdown_s: float = Field(default=3.0, ge=0, le=30)
    by_role: bool = False


class RestartIn(BaseModel):
    side: Literal["a", "b", "both"] = "both"


class ShareIn(BaseModel):
    node_id: str = Field(pattern=_NODE_RE)
    token: str = Field(min_length=MIN_TOKEN_LEN, max_length=256)


@router.get("/sources")
async def sources(user: CurrentUser, hub: HubDep) -> list[dict[str, Any]]:
    """This server's nodes (a KSCC side needs an online one)."""
    return [{"node_id": s.id, "connected": s.connected, "model": s.sensor.model,
             "joint_set": s.sensor.joint_set}
            for s in sorted(hub.registry.nodes.values(), key=lambda s: s.id)]


@router.post("/session")
async def start_session(request: Request, body: SessionIn, user: CurrentUser) -> dict[str, Any]:
    """Start calibrating both sides (after the countdown); replaces a running session."""
    m = manager(request.app)

    def spec(s: SourceIn) -> SourceSpec:
        return SourceSpec(s.kind, s.node_id, s.url if s.kind == "remote" else None,
                          s.token if s.kind == "remote" else None)

    try:
        sess = await m.start(spec(body.a), spec(body.b), body.countdown_s, body.by_role)
    except PeerNotAllowedError as e:
        raise HTTPException(status.HTTP_403_FORBIDDEN, str(e)) from None
    return _running(sess)


#: Said while no session runs (``GET /session``'s idle state; 404 of a restart).
IDLE_MESSAGE = "no KSCC session; choose two skeleton sources and start one"


def _running(sess: KsccSession) -> dict[str, Any]:
    """A running session's JSON, marked as running (as ``GET /session`` answers it)."""
    return {"running": True, **sess.status()}


def _session(request: Request) -> KsccSession:
    sess = manager(request.app).session
    if sess is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, IDLE_MESSAGE)
    return sess


@router.get("/session")
async def get_session(request: Request, user: CurrentUser) -> dict[str, Any]:
    """Both sides' progress and the comparison, or the idle state.

    No session is a normal state, not an error: the page polls this, and a 404 would be
    logged by the browser on every poll.
    """
    sess = manager(request.app).session
    if sess is None:
        return {"running": False, "message": IDLE_MESSAGE, "sides": None, "by_role": None,
                "comparison": None}
    return _running(sess)


@router.post("/session/restart")
async def restart(request: Request, body: RestartIn, user: CurrentUser) -> dict[str, Any]:
    """Recalibrate one side or both (countdown again)."""
    sess = _session(request)
    for k in ("a", "b") if body.side == "both" else (body.side,):
        sess.sides[k].restart()
    return _running(sess)


@router.delete("/session", status_code=204)
async def stop_session(request: Request, user: CurrentUser) -> None:
    """End the session and its links."""
    await manager(request.app).stop()


@router.get("/shares")
async def list_shares(request: Request, user: CurrentUser) -> list[dict[str, Any]]:
    """Nodes of this server shared with other sites (tokens are not shown again)."""
    return [{"node_id": n} for n in sorted(manager(request.app).shares)]


@router.post("/shares", status_code=201)
async def share(request: Request, body: ShareIn, user: CurrentUser, hub: HubDep
                ) -> dict[str, Any]:
    """Share a node with another site; give them this server's address and the token."""
    if hub.registry.get(body.node_id) is None:
        raise InputError(f"no node {body.node_id!r} on this server; pick one of "
                         f"{sorted(hub.registry.nodes) or 'none yet'}")
    if not re.search(r"[A-Za-z]", body.token) or not re.search(r"\d", body.token):
        raise InputError("use a link token with letters and digits (≥ 16 characters), e.g. "
                         "the suggested random one")
    manager(request.app).shares[body.node_id] = body.token
    return {"node_id": body.node_id}


@router.delete("/shares/{node_id}", status_code=204)
async def unshare(request: Request, node_id: str, user: CurrentUser) -> None:
    """Stop sharing a node (its open links close within a second)."""
    if manager(request.app).shares.pop(node_id, None) is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"node {node_id!r} is not shared")


async def _link(ws: WebSocket) -> None:
    await manager(ws.app).serve_link(ws)


# A plain Starlette route: the link authenticates by its token, not by a console login.
router.add_websocket_route("/kscc/link", _link)  # the prefix is not applied here


# ------------------------------------------------------------------- active area


def _trap(t: Trapezoid) -> dict[str, float]:
    return {"near_m": t.near_m, "far_m": t.far_m, "depth_m": t.depth_m,
            "near_width_m": t.near_width_m, "far_width_m": t.far_width_m,
            "near_half_width_m": t.near_half_width_m, "far_half_width_m": t.far_half_width_m}


def presets(height_m: float, tilt_deg: float = 0.0) -> dict[str, Any]:
    """Trapezoid (or why there is none) for every preset at this height and tilt."""
    out: dict[str, Any] = {}
    for key, label in PRESETS.items():
        m = SENSOR_MODELS[key]
        entry: dict[str, Any] = {"label": label, "hfov_deg": m.hfov_deg, "vfov_deg": m.vfov_deg,
                                 "min_range_m": m.min_range_m, "max_range_m": m.max_range_m}
        try:
            entry["trapezoid"] = _trap(preset_trapezoid(key, height_m, tilt_deg=tilt_deg))
        except InputError:
            entry["trapezoid"] = None
            # the feet enter the view farther out the higher the sensor; beyond the range
            # limit (or with too much tilt) no spot shows the whole body
            entry["problem"] = (f"no floor spot shows a whole 1.8 m person within its "
                                f"{m.min_range_m:g}–{m.max_range_m:g} m range at this height "
                                "and tilt; mount it nearer 1 m or tilt it less")
        out[key] = entry
    return out


def _areas(hub: Any) -> list[dict[str, Any]]:
    rows = []
    for s in sorted(hub.registry.nodes.values(), key=lambda s: s.id):
        row: dict[str, Any] = {"node_id": s.id, "connected": s.connected, "model": s.sensor.model,
                               "preset": model_key(s.sensor.model)}
        if s.sensor.T_world_sensor is not None:
            h, tilt = pose_numbers(np.asarray(s.sensor.T_world_sensor, dtype=float))
            row["height_m"], row["tilt_deg"] = h, tilt
            if h > 0:
                row["presets"] = presets(h, tilt)
        else:
            row["height_m"] = None
        area = node_area(s)
        if isinstance(area, ActiveArea):
            row["polygon"] = [[round(float(x), 3) for x in p[:2]] for p in area.polygon]
        else:
            row["problem"] = area
        rows.append(row)
    return rows


@router.get("/active-area")
async def active_area(request: Request, user: CurrentUser, hub: HubDep) -> list[dict[str, Any]]:
    """Each node's active-area trapezoids from its height (and tilt); drawn in 3D too."""
    layer = getattr(request.app.state, "active_areas", None)
    if layer is not None:
        layer.redraw()
    return _areas(hub)


@router.get("/trapezoid")
async def trapezoid(user: CurrentUser, height_m: float = Query(1.0, gt=0, le=5),
                    tilt_deg: float = Query(0.0, ge=-45, le=45)) -> dict[str, Any]:
    """The presets' trapezoids at any height and tilt (seed 004's Kinect v1 at 1 m:
    254 cm, 400 cm, half-widths 138/217 cm)."""
    return {"height_m": height_m, "tilt_deg": tilt_deg, "presets": presets(height_m, tilt_deg)}
