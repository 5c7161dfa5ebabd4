"""Server storage: disk usage per subject, recording detail with transfer progress,
transfer retry, deletion with confirmation, recordings not yet filed under a session.

The router's lifespan runs :class:`app.server.datasync.DataSync` (automatic transfer
after stop, retries, database mirror of every recording's state).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator
from collections.abc import Set as AbstractSet
from contextlib import asynccontextmanager
from datetime import UTC, datetime
from typing import Annotated, Any

from fastapi import APIRouter, FastAPI, HTTPException, Query, Request, status
from pydantic import BaseModel, Field
from sqlalchemy import func, select

from app.api.deps import CurrentUser, DbDep, ExportsDep, HubDep
from app.api.limits import BoundedRoute
from app.api.routes._data import (
    audit_event,
    check_confirm,
    datasync_of,
    delete_rows,
    delete_unfiled,
    get_recording,
    layout_of,
    node_copies,
    recording_json,
    resume_deletions,
)
from app.db import data as m
from app.server.cleanup import clean_stale
from app.server.datasync import DataSync
from app.server.storage import StorageLayout, usage_index
from engine.errors import InputError

log = logging.getLogger("gaitrig.storage")


@asynccontextmanager
async def _lifespan(app: FastAPI) -> AsyncIterator[None]:
    layout = StorageLayout(app.state.settings.data_dir)
    with app.state.db_sessions() as db:  # a deletion the last run did not finish
        resume_deletions(db, app.state.hub, layout)
    ds = DataSync(app.state.hub, app.state.db_sessions, layout,
                  check_interval_s=app.state.settings.storage_check_interval_s)
    app.state.datasync = ds
    ds.start()
    # leftovers of uploads cut short go, then the bytes of every recording are measured
    # (GET /api/storage): in the background
    scan = asyncio.create_task(asyncio.to_thread(_start_up_files, app, layout))
    try:
        yield
    finally:
        await ds.stop()
        with contextlib.suppress(Exception):
            await scan


def _start_up_files(app: FastAPI, layout: StorageLayout) -> None:
    """The start-up clean-up (:func:`app.server.cleanup.clean_stale`) and measurement of
    the data folder (:meth:`app.server.storage.UsageIndex.rescan`); in a worker thread."""
    try:
        with app.state.db_sessions() as db:
            refs = {(str(a), str(b)) for a, b in db.execute(select(
                m.ReferenceImport.__table__.c.recording_id,
                m.ReferenceImport.__table__.c.stored_name))}
        clean_stale(layout.data_dir, refs)
    except Exception:  # the server runs without it: logged
        log.exception("start-up clean-up of the data folder failed")
    usage_index(layout.data_dir).rescan()


router = APIRouter(prefix="/storage", route_class=BoundedRoute, tags=["data"], lifespan=_lifespan)


class Confirm(BaseModel):
    confirm: str = Field(max_length=200, description="The subject code typed again.")


class ConfirmId(BaseModel):
    confirm: str = Field(max_length=200, description="The recording id typed again.")


@router.get("")
def usage(request: Request, user: CurrentUser, db: DbDep, hub: HubDep,
          subjects_too: Annotated[bool, Query(alias="subjects", description=(
              "false: only the disk and pending deletions, without the bytes of every "
              "subject"))] = True,
          rescan: Annotated[bool, Query(description=(
              "true: measure every recording folder again first (after files were changed "
              "by hand; seconds at clinic size)"))] = False) -> dict[str, Any]:
    """Disk of the data folder, bytes stored per subject, and the node copies of deleted
    recordings still to delete (``pending_node_deletions``: node id → recording ids).

    The bytes come from the server's usage index (:class:`app.server.storage.UsageIndex`:
    kept as files arrive and go, measured in full at start-up and with ``rescan=true``;
    ``usage_scanned_at`` says when the last full measurement ended)."""
    layout = layout_of(request)
    idx = usage_index(layout.data_dir)
    if rescan:
        idx.rescan()
    subjects: list[dict[str, Any]] = []
    if subjects_too:
        # one row per subject with its recording ids joined in SQL, without the ORM: a
        # row per recording (30 000 in a clinic) took ten times as long
        s, se, r = m.Subject.__table__, m.Session.__table__, m.Recording.__table__
        rows = db.execute(select(s.c.id, s.c.project_id, s.c.code,
                                 func.aggregate_strings(r.c.id, ","))
                          .select_from(s.outerjoin(se, se.c.subject_id == s.c.id)
                                       .outerjoin(r, r.c.session_id == se.c.id))
                          .group_by(s.c.id).order_by(s.c.project_id, s.c.code, s.c.id)).all()
        recs = {x[0]: x[3].split(",") if x[3] else [] for x in rows}  # (ids have no comma)
        sizes = idx.many(i for ids in recs.values() for i in ids)
        subjects = [{"id": x[0], "project_id": x[1], "code": x[2],
                     "bytes": sum(sizes[i] for i in recs[x[0]]),
                     "n_recordings": len(recs[x[0]])} for x in rows]
    return {"disk": layout.disk(), "data_dir": str(layout.data_dir), "subjects": subjects,
            "pending_node_deletions": hub.transfers.pending_deletions(),
            "usage_scanned_at": None if idx.scanned_at is None else
            datetime.fromtimestamp(idx.scanned_at, UTC).isoformat(timespec="seconds")}


@router.get("/recordings/{rec_id}")
def recording(rec_id: str, request: Request, user: CurrentUser, db: DbDep) -> dict[str, Any]:
    """A filed recording: state (with the reason), parts, transfer progress, references."""
    r = get_recording(db, rec_id)
    d = recording_json(r, layout_of(request))
    s = r.session
    d["session"] = {"id": s.id, "date": s.date.isoformat(), "label": s.label}
    d["subject"] = {"id": s.subject.id, "code": s.subject.code,
                    "project_id": s.subject.project_id}
    return d


@router.post("/recordings/{rec_id}/transfer", status_code=202)
async def retry_transfer(rec_id: str, request: Request, user: CurrentUser, db: DbDep
                   ) -> dict[str, Any]:
    """Transfer the parts of a recording that are not on the server yet, now."""
    r = get_recording(db, rec_id)
    try:
        datasync_of(request).retry(rec_id)
    except InputError as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from exc
    return recording_json(r)


@router.post("/recordings/{rec_id}/delete")
async def delete_recording(rec_id: str, body: Confirm, request: Request, user: CurrentUser,
                           db: DbDep, hub: HubDep, exports: ExportsDep) -> dict[str, Any]:
    """Delete a recording everywhere (confirm = the subject code): rows and files on the
    server, and the parts on the nodes (an offline node deletes its part when it
    reconnects). ``node_copies`` says, per node, whether its copy is gone yet."""
    r = get_recording(db, rec_id)
    check_confirm(r.session.subject.code, body.confirm, f"recording {rec_id}")
    plan = await delete_rows(db, hub, layout_of(request), exports, [r], entry=audit_event(
        request, user, "delete", f"recording {rec_id}", f"session {r.session_id}"))
    return {"deleted": "recording", "id": rec_id, "node_copies": await node_copies(hub, plan)}


@router.post("/unfiled/{rec_id}/delete")
async def delete_unfiled_recording(rec_id: str, body: ConfirmId, request: Request,
                                   user: CurrentUser, db: DbDep, hub: HubDep) -> dict[str, Any]:
    """Delete a recording filed under no session (confirm = the recording id): the files
    on the server and the parts on the nodes, as for a filed one."""
    check_confirm(rec_id, body.confirm, f"recording {rec_id}")
    nodes = await delete_unfiled(db, hub, layout_of(request), rec_id, audit_event(
        request, user, "delete", f"recording {rec_id}", "not filed under a session"))
    return {"deleted": "recording", "id": rec_id,
            "node_copies": await node_copies(hub, {rec_id: nodes})}


@router.get("/unfiled")
def unfiled(request: Request, user: CurrentUser, db: DbDep, hub: HubDep
            ) -> list[dict[str, Any]]:
    """Recordings the server knows that belong to no session yet (attach them to one, or
    delete them: ``POST /api/storage/unfiled/{rec_id}/delete``)."""
    live = hub.recordings.recordings
    ids = _unfiled_ids(request, db, live.keys())
    recs = [r for i in ids if (r := live.get(i)) is not None]  # (one deleted meanwhile)
    return [{"id": r.id, "state": r.state, "t_start": r.t_start, "t_stop": r.t_stop,
             "nodes": sorted(r.parts)}
            for r in sorted(recs, key=lambda r: r.created, reverse=True)]


def _unfiled_ids(request: Request, db: Any, live: AbstractSet[str]) -> set[str]:
    """Ids among ``live`` (the recordings the server knows) without a row.

    A clinic's server knows tens of thousands of recordings, nearly all filed: reading
    every id (and sorting every recording) per request made the list ten times slower
    than on a new server. A recording once filed stays filed while the server knows it
    (nothing unfiles one; deleting its row takes it out of the server's list first), so
    the filed ids are kept between requests and only the others are asked about: the
    unfiled few and those made since (bench/storage_scale.py).
    """
    known: set[str] | None = getattr(request.app.state, "filed_ids", None)
    if known is None:
        known = request.app.state.filed_ids = set()
    ask = set(live - known)  # (one pass in C over the ids)
    t = m.Recording.__table__
    if len(ask) > 2000:  # the first request: every id in one query
        found = set(db.execute(select(t.c.id)).scalars())
    else:
        found, todo = set(), sorted(ask)
        for i in range(0, len(todo), 500):
            found.update(db.execute(select(t.c.id).where(t.c.id.in_(todo[i:i + 500])))
                         .scalars())
    known |= found
    if len(known) > len(live) + 1000:  # deleted ones: forgotten now and then
        known.intersection_update(live)
    return ask - found
