"""Synchronous recordings: start, stop, list, inspect."""

from __future__ import annotations

from typing import Any, Literal

from fastapi import APIRouter, HTTPException, status
from pydantic import BaseModel, Field

from app.api.deps import CurrentUser, HubDep
from app.api.limits import BoundedRoute
from engine.errors import InputError

router = APIRouter(prefix="/recordings", route_class=BoundedRoute, tags=["recordings"])


class StartIn(BaseModel):
    streams: list[Literal["depth", "color", "body_index"]] = Field(
        default_factory=list, max_length=3,  # stored joined in a 120-character column
        description="Image streams to record besides skeletons.")
    image_every: int = Field(default=1, ge=1, le=1000, description="Images of every N-th frame.")


@router.get("")
async def list_recordings(user: CurrentUser, hub: HubDep) -> list[dict[str, Any]]:
    """All recordings, newest first, with per-node part states."""
    recs = sorted(hub.recordings.recordings.values(), key=lambda r: r.created, reverse=True)
    return [hub.recordings.to_dict(r) for r in recs]


@router.post("", status_code=201)
async def start_recording(body: StartIn, user: CurrentUser, hub: HubDep) -> dict[str, Any]:
    """Start recording on every connected node at a common server time."""
    try:
        rec = hub.recordings.start(list(body.streams), body.image_every)
    except InputError as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from exc
    return hub.recordings.to_dict(rec)


@router.get("/{rec_id}")
async def get_recording(rec_id: str, user: CurrentUser, hub: HubDep) -> dict[str, Any]:
    """One recording."""
    rec = hub.recordings.recordings.get(rec_id)
    if rec is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no recording {rec_id!r}")
    return hub.recordings.to_dict(rec)


@router.post("/{rec_id}/transfer", status_code=202)
async def transfer_recording(rec_id: str, user: CurrentUser, hub: HubDep) -> dict[str, Any]:
    """Copy every closed part to the server, verified chunk by chunk (runs in background;
    follow the parts' ``state`` and ``transfer_progress``)."""
    if rec_id not in hub.recordings.recordings:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no recording {rec_id!r}")
    try:
        hub.transfers.start(rec_id)
    except InputError as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from exc
    return hub.recordings.to_dict(hub.recordings.recordings[rec_id])


@router.post("/{rec_id}/stop")
async def stop_recording(rec_id: str, user: CurrentUser, hub: HubDep) -> dict[str, Any]:
    """Stop a recording now on all its nodes."""
    if rec_id not in hub.recordings.recordings:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no recording {rec_id!r}")
    try:
        rec = hub.recordings.stop(rec_id)
    except InputError as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from exc
    return hub.recordings.to_dict(rec)
