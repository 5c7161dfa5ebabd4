"""Synchronous recordings: start, stop, list, inspect.

Besides the recording manager's view (:meth:`app.server.recording.RecordingManager.to_dict`,
with ``save_error``), each answer says what the server knows about each part and the
rig: a part's ``images_skipped`` (frames recorded without their images because the
node's encoder fell behind; stored in the part's database row when the part arrives on
the server, read from the server copy's ``meta.json`` for a part without one, e.g. one
that arrived before the column existed or a recording filed under no session; ``null``
until the part is on the server) and ``not_in_recording`` (nodes connected while the
recording ran that are not part of it, with why).
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Collection
from pathlib import Path
from typing import Annotated, Any, Literal

from fastapi import APIRouter, HTTPException, Query, Response, status
from pydantic import BaseModel, Field
from sqlalchemy import select
from sqlalchemy.orm import Session as DbSession

from app.api.deps import CurrentUser, DbDep, HubDep, SettingsDep
from app.api.limits import BoundedRoute
from app.api.routes._paging import LimitQ, OffsetQ, SearchQ, page_of, set_total
from app.db.data import RecordingPart
from app.server.hub import Hub
from app.server.recording import Recording
from app.server.storage import StorageLayout
from engine.errors import InputError

router = APIRouter(prefix="/recordings", route_class=BoundedRoute, tags=["recordings"])


class StartIn(BaseModel):
    streams: list[Literal["depth", "color", "body_index"]] = Field(
        default_factory=list, max_length=3,  # stored joined in a 120-character column
        description="Image streams to record besides skeletons.")
    image_every: int = Field(default=1, ge=1, le=1000, description="Images of every N-th frame.")


# meta.json path -> (mtime_ns, images_skipped): pages poll recordings twice a second
_SKIPPED: dict[Path, tuple[int, int]] = {}
_SKIPPED_MAX = 4096


def _images_skipped(layout: StorageLayout, rec_id: str, node_id: str) -> int | None:
    """Frames of a part recorded without their images, from the server copy's
    ``meta.json`` (a part recorded before the count existed has none: 0); ``None`` when
    the copy or its meta cannot be read."""
    try:
        path = layout.part_dir(rec_id, node_id) / "meta.json"
        mtime = path.stat().st_mtime_ns
    except (InputError, OSError):
        return None
    hit = _SKIPPED.get(path)
    if hit is not None and hit[0] == mtime:
        return hit[1]
    try:
        meta = json.loads(path.read_text())
        n = int(meta.get("images_skipped", 0)) if isinstance(meta, dict) else 0
    except (OSError, ValueError, TypeError):
        return None
    if len(_SKIPPED) >= _SKIPPED_MAX:
        _SKIPPED.clear()
    _SKIPPED[path] = (mtime, n)
    return n


_ORDER_LOCK = threading.Lock()
_order: tuple[tuple[Recording, ...], list[Recording]] = ((), [])


def _newest_first(recordings: dict[str, Recording]) -> list[Recording]:
    """The server's recordings, newest first (a new list: the caller may filter it).

    Sorting a clinic's tens of thousands of recordings per page took as long as the rest
    of the page, so the order is kept while the same recordings are known (one pass in C
    compares them; a recording's ``created`` never changes); any added, removed or
    replaced one sorts them again.
    """
    global _order
    now = tuple(recordings.values())
    with _ORDER_LOCK:
        kept, order = _order
    if kept != now:
        order = sorted(now, key=lambda r: r.created, reverse=True)
        with _ORDER_LOCK:
            _order = (now, order)
    return list(order)


def _not_in_recording(hub: Hub, rec: Recording) -> list[dict[str, Any]]:
    """Nodes connected at some time while ``rec`` ran that have no part in it.

    The registry keeps only each node's latest connection, so a node that joined during
    the recording and reconnected after its stop is not listed.
    """
    end = rec.t_stop if rec.t_stop is not None else time.time()
    out = []
    for s in sorted(hub.registry.nodes.values(), key=lambda s: s.id):
        if s.id in rec.parts or s.connected_at is None or s.connected_at > end:
            continue
        if not s.connected and (s.disconnected_at or 0.0) < rec.t_start:
            continue  # gone before the start
        if s.connected_at > rec.created:
            hms = time.strftime("%H:%M:%S", time.gmtime(s.connected_at))
            why = f"connected at {hms} UTC, after the start; it records from the next start"
        else:
            why = "its clock was not measured yet at the start"
        out.append({"node_id": s.id, "connected_at": s.connected_at, "reason": why})
    return out


def _stored_skipped(db: DbSession, rec_ids: Collection[str] | None = None
                    ) -> dict[tuple[str, str], int]:
    """``images_skipped`` stored in the part rows, by ``(rec_id, node_id)`` (of
    ``rec_ids`` only, if given); parts without a stored count are left out."""
    q = select(RecordingPart.recording_id, RecordingPart.node_id,
               RecordingPart.images_skipped).where(RecordingPart.images_skipped.is_not(None))
    if rec_ids is not None:
        q = q.where(RecordingPart.recording_id.in_(list(rec_ids)))
    return {(r, n): k for r, n, k in db.execute(q) if k is not None}


def _view(hub: Hub, layout: StorageLayout, rec: Recording,
          stored: dict[tuple[str, str], int] | None = None) -> dict[str, Any]:
    """The manager's JSON of ``rec`` with ``images_skipped`` per part (from ``stored``,
    see :func:`_stored_skipped`, else from the server copy's meta.json) and
    ``not_in_recording``."""
    d = hub.recordings.to_dict(rec)
    for p in d["parts"]:
        if not p.get("on_server"):
            p["images_skipped"] = None
            continue
        n = (stored or {}).get((rec.id, p["node_id"]))
        p["images_skipped"] = n if n is not None else _images_skipped(layout, rec.id,
                                                                       p["node_id"])
    d["not_in_recording"] = _not_in_recording(hub, rec)
    return d


#: Recordings per page of ``GET /api/recordings``: by default, and at most.
RECORDINGS_PAGE, RECORDINGS_PAGE_MAX = 100, 500
LiveState = Literal["recording", "stopping", "on_nodes", "transferring", "complete",
                    "incomplete"]


@router.get("")
async def list_recordings(
        response: Response, user: CurrentUser, hub: HubDep, settings: SettingsDep,
        db: DbDep,
        ids: Annotated[str | None, Query(max_length=20000, description=(
            "Comma-separated recording ids: only these (unknown ids are left out).")
        )] = None,
        state: Annotated[LiveState | None, Query(description="Only recordings in this state.")
                         ] = None,
        q: SearchQ = None, limit: LimitQ = None, offset: OffsetQ = 0) -> list[dict[str, Any]]:
    """The server's recordings (or those in ``ids``), newest first, with per-node part
    states, a page at a time (``limit`` ≤ 500, default 100, 500 with ``ids``; ``offset``;
    ``X-Total-Count`` header), ``state`` and ``q`` (part of the id) filtering them.

    Only the page's recordings are looked at further: one query for their stored
    ``images_skipped``, a ``meta.json`` read for a part on the server without one.
    """
    # a subject's recordings asked by id come whole (up to the largest page)
    page = page_of(limit, offset, RECORDINGS_PAGE if ids is None else RECORDINGS_PAGE_MAX,
                   RECORDINGS_PAGE_MAX)
    recs = _newest_first(hub.recordings.recordings)
    if ids is not None:
        want = {i.strip() for i in ids.split(",") if i.strip()}
        recs = [r for r in recs if r.id in want]
    if state is not None:
        recs = [r for r in recs if r.state == state]
    if q and q.strip():
        needle = q.strip().lower()
        recs = [r for r in recs if needle in r.id.lower()]
    set_total(response, len(recs))
    recs = recs[page.offset:page.offset + page.limit]
    layout = StorageLayout(settings.data_dir)
    stored = _stored_skipped(db, [r.id for r in recs]) if recs else {}
    return [_view(hub, layout, r, stored) for r in recs]


@router.post("", status_code=201)
async def start_recording(body: StartIn, user: CurrentUser, hub: HubDep,
                          settings: SettingsDep) -> dict[str, Any]:
    """Start recording on every connected node at a common server time."""
    try:
        rec = hub.recordings.start(list(body.streams), body.image_every)
    except InputError as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from exc
    return _view(hub, StorageLayout(settings.data_dir), rec)


@router.get("/{rec_id}")
async def get_recording(rec_id: str, user: CurrentUser, hub: HubDep,
                        settings: SettingsDep, db: DbDep) -> dict[str, Any]:
    """One recording."""
    rec = hub.recordings.recordings.get(rec_id)
    if rec is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no recording {rec_id!r}")
    return _view(hub, StorageLayout(settings.data_dir), rec, _stored_skipped(db, [rec_id]))


@router.post("/{rec_id}/transfer", status_code=202)
async def transfer_recording(rec_id: str, user: CurrentUser, hub: HubDep,
                             settings: SettingsDep) -> dict[str, Any]:
    """Copy every closed part to the server, verified chunk by chunk (runs in background;
    follow the parts' ``state`` and ``transfer_progress``)."""
    if rec_id not in hub.recordings.recordings:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no recording {rec_id!r}")
    try:
        hub.transfers.start(rec_id)
    except InputError as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from exc
    return _view(hub, StorageLayout(settings.data_dir), hub.recordings.recordings[rec_id])


@router.post("/{rec_id}/stop")
async def stop_recording(rec_id: str, user: CurrentUser, hub: HubDep,
                         settings: SettingsDep) -> dict[str, Any]:
    """Stop a recording now on all its nodes."""
    if rec_id not in hub.recordings.recordings:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no recording {rec_id!r}")
    try:
        rec = hub.recordings.stop(rec_id)
    except InputError as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from exc
    return _view(hub, StorageLayout(settings.data_dir), rec)
