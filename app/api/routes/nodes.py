"""Sensor nodes: health, latest skeleton, live images.

``GET /api/nodes`` → list of health records (``id``, ``connected``, ``fps``,
``dropped_frames``, ``clock_offset_ms``, ``clock_uncertainty_ms``, ``clock_drift_ppm``,
``disk_free_bytes``, ``storage`` (held, verified, purgeable bytes), ``warnings`` in plain
words, ...).
"""

from __future__ import annotations

import asyncio
import itertools
from typing import Any, Literal

import numpy as np
from fastapi import APIRouter, HTTPException, Request, Response, status
from pydantic import BaseModel, Field

from app.api.deps import CurrentUser, HubDep
from app.api.limits import BoundedRoute
from app.nodes.protocol import Snapshot, Subscribe, dump
from app.server.registry import NodeSession

router = APIRouter(prefix="/nodes", route_class=BoundedRoute, tags=["nodes"])


class NodeWarningOut(BaseModel):
    """A warning of a node's sensor backend (``warning`` message, docs/backbone.md)."""

    at: float = Field(description="Server time it was last raised (s since the epoch).")
    text: str
    repeats: int = Field(description="How many times it was raised.")


class NodeLensOut(BaseModel):
    """The lenses a node announced when it connected (``sensor_lens``, docs/backbone.md)."""

    source: str = Field(description="Where they come from (\"factory calibration\").")
    depth_dist: list[float] | None = Field(
        description="OpenCV distortion of the depth camera ([]: none; null: not reported).")
    color_dist: list[float] | None = Field(description="The same for the colour camera.")


class NodeHealth(BaseModel):
    """Health of one node (times in server seconds since the epoch)."""

    id: str
    connected: bool
    backend: str
    model: str
    fps: float
    frames: int
    dropped_frames: int
    clock_offset_ms: float | None
    clock_uncertainty_ms: float | None
    clock_drift_ppm: float | None
    clock_rtt_ms: float | None
    clock_at: float
    clock_warning: bool
    disk_free_bytes: int | None
    ring_seconds: float | None
    storage: dict[str, Any] | None = Field(
        default=None,
        description="The node's recordings folder: held_bytes/parts, verified_bytes/parts "
        "(the server holds verified copies), purgeable_bytes, unverified_bytes/parts (the "
        "only copies), keep_verified_days, min_free_bytes (floor), purged_parts/bytes since "
        "the node started, last_purge.")
    connected_at: float | None
    last_seen: float | None
    rejected_messages: int
    last_rejection: str | None
    warnings: list[str]
    node_warnings: list[NodeWarningOut] = Field(
        default_factory=list,
        description="What the node's sensor backend warned about after it connected, newest "
        "first (at most 5 distinct texts; a repeat updates its entry).")
    node_warnings_dropped: int = Field(
        default=0, description="Warnings the node sent beyond the server's rate limit.")
    lens: NodeLensOut | None = Field(
        default=None, description="The lenses the node announced; null: none reported (an "
        "older node, a replay): the live view draws it as a pinhole camera unless a "
        "calibration recorded its lens.")
    diag: dict[str, float] = Field(default_factory=dict)


class SubscribeIn(BaseModel):
    streams: list[Literal["depth", "color", "body_index"]]
    fps: float = Field(default=2.0, ge=0, le=30)
    scale: float = Field(default=0.5, gt=0, le=1)
    format: Literal["jpeg", "png"] = "jpeg"


def _node(hub: Any, node_id: str) -> NodeSession:
    s = hub.registry.get(node_id)
    if s is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"no node {node_id!r}; GET /api/nodes lists the known nodes")
    return s


@router.get("", response_model=list[NodeHealth])
async def list_nodes(user: CurrentUser, hub: HubDep) -> list[dict[str, Any]]:
    """Every node seen since the server started, with its health."""
    return [hub.registry.health(s) for s in sorted(hub.registry.nodes.values(),
                                                   key=lambda s: s.id)]


@router.get("/{node_id}", response_model=NodeHealth)
async def get_node(node_id: str, user: CurrentUser, hub: HubDep) -> dict[str, Any]:
    """Health of one node."""
    return hub.registry.health(_node(hub, node_id))


@router.get("/{node_id}/sensor")
async def get_sensor(node_id: str, user: CurrentUser, hub: HubDep) -> dict[str, Any]:
    """What the node reported about its sensor (sizes, intrinsics, known pose)."""
    return _node(hub, node_id).sensor.model_dump()


@router.get("/{node_id}/skeleton")
async def get_skeleton(node_id: str, user: CurrentUser, hub: HubDep) -> dict[str, Any]:
    """Newest skeleton frame (sensor frame, metres; ``t`` in server time)."""
    sk = _node(hub, node_id).skeleton
    if sk is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"node {node_id} sent no skeleton yet")
    # JSON has no NaN: joints without an estimate become null
    pos = np.where(np.isfinite(sk.positions), sk.positions, np.nan).astype(object)
    pos[~np.isfinite(sk.positions)] = None
    return {"seq": sk.seq, "t": sk.t_server, "t_local": sk.t_local, "body_ids": sk.body_ids,
            "positions": pos.tolist(), "states": sk.states.tolist()}


@router.post("/{node_id}/subscribe", status_code=202)
async def subscribe(node_id: str, body: SubscribeIn, user: CurrentUser, hub: HubDep,
                    request: Request) -> dict[str, Any]:
    """Ask a node to stream images at ``fps`` (0 stops); read them from ``/images/{stream}``.

    While the Live page or the 3D view streams this node, the live view's subscription
    stays in force (16-bit PNG depth and body index at its scale) and the requested
    streams are added to it, at the higher rate; ``sent`` says what the node streams now.
    Your subscription applies as asked once nobody watches the live view.
    """
    s = _node(hub, node_id)
    if s.send is None:
        raise HTTPException(status.HTTP_409_CONFLICT, f"node {node_id} is offline")
    sub = Subscribe(**body.model_dump())
    live = getattr(request.app.state, "live", None)
    if live is None:  # no live services (e.g. still starting): nothing to share with
        await s.send(dump(sub))
        sent: Subscribe | None = sub if sub.fps > 0 and sub.streams else None
    else:
        sent = await live.streams.request(node_id, sub)
    return {"node": node_id, "requested": body.model_dump(),
            "sent": sent.model_dump(exclude={"type"}) if sent is not None else None,
            "shared_with_live_view": sent is not None and sent != sub}


class SnapshotIn(BaseModel):
    streams: list[Literal["depth", "color", "body_index"]] = Field(min_length=1)
    scale: float = Field(default=1.0, gt=0, le=1)
    format: Literal["jpeg", "png"] = "png"


_snapshot_ids = itertools.count(1)


@router.post("/{node_id}/snapshot")
async def snapshot(node_id: str, body: SnapshotIn, user: CurrentUser,
                   hub: HubDep) -> dict[str, Any]:
    """Ask a node for one image of each stream now; waits (≤ 10 s) until they arrived."""
    s = _node(hub, node_id)
    if s.send is None:
        raise HTTPException(status.HTTP_409_CONFLICT, f"node {node_id} is offline")
    req_id = next(_snapshot_ids)
    await s.send(dump(Snapshot(req_id=req_id, **body.model_dump())))
    deadline = asyncio.get_running_loop().time() + 10.0
    while asyncio.get_running_loop().time() < deadline:
        got = {k: v for k, v in s.images.items() if v.header.get("req_id") == req_id}
        if len(got) == len(set(body.streams)):
            return {"req_id": req_id, "images": {
                k: {"t": v.t_server, "format": v.format,
                    "url": f"/api/nodes/{node_id}/images/{k}"} for k, v in got.items()}}
        await asyncio.sleep(0.05)
    raise HTTPException(status.HTTP_504_GATEWAY_TIMEOUT,
                        f"node {node_id} sent no {', '.join(body.streams)} image within 10 s "
                        "(a node started with --no-images has none)")


@router.get("/{node_id}/images/{stream}")
async def get_image(node_id: str, stream: Literal["depth", "color", "body_index"],
                    user: CurrentUser, hub: HubDep) -> Response:
    """Newest image of a subscribed stream (JPEG or PNG)."""
    img = _node(hub, node_id).images.get(stream)
    if img is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"no {stream} image from {node_id}; subscribe first")
    media = "image/jpeg" if img.format == "jpeg" else "image/png"
    return Response(img.data, media_type=media,
                    headers={"X-Gaitrig-Time": repr(img.t_server), "Cache-Control": "no-store"})
