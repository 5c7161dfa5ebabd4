"""Server storage: disk usage per subject, recording detail with transfer progress,
transfer retry, deletion with confirmation, recordings not yet filed under a session.

The router's lifespan runs :class:`app.server.datasync.DataSync` (automatic transfer
after stop, retries, database mirror of every recording's state).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import re
import threading
import time
from collections.abc import AsyncIterator
from collections.abc import Set as AbstractSet
from contextlib import asynccontextmanager
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Annotated, Any

from fastapi import APIRouter, FastAPI, HTTPException, Query, Request, Response, status
from pydantic import BaseModel, Field
from sqlalchemy import event, func, select

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


_WATCHED_TABLES = re.compile(r"\b(subjects|sessions|recordings)\b", re.IGNORECASE)
#: columns of those tables the storage overview shows or groups by
_WATCHED_COLUMNS = frozenset({"id", "project_id", "code", "subject_id", "session_id"})
_SET_COLUMN = re.compile(r"\"?(\w+)\"?\s*=")


def _changes_overview(statement: str) -> bool:
    """Whether an SQL statement may change what the storage overview lists (a subject,
    session or recording added, removed, renamed or moved); a recording's state written
    back (the data sync does so all the time) does not."""
    head = statement.lstrip()[:8].upper()
    if head.startswith(("SELECT", "PRAGMA", "SAVEPOIN", "RELEASE", "BEGIN", "COMMIT",
                        "ROLLBACK")):
        return False
    if not _WATCHED_TABLES.search(statement):
        return False
    if head.startswith("UPDATE"):
        set_clause = re.split(r"\sWHERE\s", re.split(r"\sSET\s", statement, maxsplit=1,
                                                     flags=re.IGNORECASE)[-1],
                              maxsplit=1, flags=re.IGNORECASE)[0]
        return bool(_WATCHED_COLUMNS & {c.lower() for c in _SET_COLUMN.findall(set_clause)})
    return True  # INSERT, DELETE, a schema change


class _DbGeneration:
    """Grows whenever this process writes a subject, session or recording row, again
    when that connection goes back to the pool (after its commit or rollback: an
    answer read from the old rows meanwhile is not kept under the new count)."""

    def __init__(self, engine: Any) -> None:
        self.value = 0
        event.listen(engine, "after_cursor_execute", self._executed)
        event.listen(engine.pool, "checkin", self._checked_in)

    def _executed(self, conn: Any, _cursor: Any, statement: str, *_args: Any) -> None:
        if _changes_overview(statement):
            conn.info["gaitrig_overview_written"] = True
            self.value += 1

    def _checked_in(self, _dbapi_conn: Any, record: Any) -> None:
        if record is not None and record.info.pop("gaitrig_overview_written", False):
            self.value += 1


_GENERATION_LOCK = threading.Lock()


def _db_generation(request: Request) -> _DbGeneration:
    """The app's :class:`_DbGeneration` (listening from the first request on)."""
    gen: _DbGeneration | None = getattr(request.app.state, "overview_generation", None)
    if gen is None:
        with _GENERATION_LOCK:
            gen = getattr(request.app.state, "overview_generation", None)
            if gen is None:
                engine = request.app.state.db_sessions.kw["bind"]
                gen = request.app.state.overview_generation = _DbGeneration(engine)
    return gen


@dataclass
class _Overview:
    """The subjects' part of ``GET /api/storage``, kept with what it was built from."""

    db_generation: int
    usage_version: int
    stamps: tuple[dict[str, int], dict[str, int]]
    checked_at: float  # time.monotonic() of the stamps' last listing
    rows: list[Any]  # (subject id, project id, code, its recording ids)
    subjects_json: bytes


def _subject_rows(db: Any) -> list[Any]:
    """(id, project id, code, recording ids) of every subject, in the overview's order."""
    # one row per subject with its recording ids joined in SQL, without the ORM: a row
    # per recording (30 000 in a clinic) took ten times as long
    s, se, r = m.Subject.__table__, m.Session.__table__, m.Recording.__table__
    rows = db.execute(select(s.c.id, s.c.project_id, s.c.code,
                             func.aggregate_strings(r.c.id, ","))
                      .select_from(s.outerjoin(se, se.c.subject_id == s.c.id)
                                   .outerjoin(r, r.c.session_id == se.c.id))
                      .group_by(s.c.id).order_by(s.c.project_id, s.c.code, s.c.id)).all()
    return [(x[0], x[1], x[2], x[3].split(",") if x[3] else []) for x in rows]  # (no comma
    # in an id)


def _dumps(obj: Any) -> bytes:
    """JSON as FastAPI's ``JSONResponse`` renders it (so a kept answer is the same bytes)."""
    return json.dumps(obj, ensure_ascii=False, allow_nan=False, indent=None,
                      separators=(",", ":")).encode("utf-8")


#: Seconds an overview is given without listing the recordings' folders again. Every
#: change the server makes below them is reported to the usage index (a transfer ended,
#: an analysis or a reference written, a deletion, the periodic check's finds), which
#: makes a new one at once; the listing (a ``stat`` per recording folder: 15-40 ms for
#: 2 000 on a loaded machine, and a clinic keeps every recording) only catches a file
#: put at the top of a folder by hand.
STAMPS_MAX_AGE_S = 10.0


def _subjects_json(request: Request, db: Any, idx: Any) -> bytes:
    """The overview's ``subjects`` list as JSON, built again only when a subject,
    session or recording row was written, the usage index's sizes changed, or (listed
    at most every :data:`STAMPS_MAX_AGE_S`) a recording's folder stamp did.

    A clinic's list is thousands of subjects: building it per request (the joined query,
    a size per recording, FastAPI's encoding of every item) took 6-8 times what a new
    server's did (bench/storage_scale.py)."""
    gen = _db_generation(request)
    db_generation, usage_version = gen.value, idx.version  # before anything is read
    kept: _Overview | None = getattr(request.app.state, "storage_overview", None)
    if kept is not None and (kept.db_generation, kept.usage_version) == (db_generation,
                                                                         usage_version):
        now = time.monotonic()
        if now - kept.checked_at < STAMPS_MAX_AGE_S:
            return kept.subjects_json
        stamps = idx.stamps()
        if stamps == kept.stamps:
            kept.checked_at = now
            return kept.subjects_json
    else:
        stamps = idx.stamps()
    checked_at = time.monotonic()
    rows = kept.rows if kept is not None and kept.db_generation == db_generation else \
        _subject_rows(db)
    sizes = idx.many((i for x in rows for i in x[3]), stamps)
    out = _dumps([{"id": x[0], "project_id": x[1], "code": x[2],
                   "bytes": sum(sizes[i] for i in x[3]), "n_recordings": len(x[3])}
                  for x in rows])
    request.app.state.storage_overview = _Overview(db_generation, usage_version, stamps,
                                                   checked_at, rows, out)
    return out


@router.get("", response_model=dict[str, Any])
def usage(request: Request, user: CurrentUser, db: DbDep, hub: HubDep,
          subjects_too: Annotated[bool, Query(alias="subjects", description=(
              "false: only the disk and pending deletions, without the bytes of every "
              "subject"))] = True,
          rescan: Annotated[bool, Query(description=(
              "true: measure every recording folder again first (after files were changed "
              "by hand; seconds at clinic size)"))] = False) -> Response:
    """Disk of the data folder, bytes stored per subject, and the node copies of deleted
    recordings still to delete (``pending_node_deletions``: node id → recording ids).

    The bytes come from the server's usage index (:class:`app.server.storage.UsageIndex`:
    kept as files arrive and go, measured in full at start-up and with ``rescan=true``;
    ``usage_scanned_at`` says when the last full measurement ended)."""
    layout = layout_of(request)
    idx = usage_index(layout.data_dir)
    if rescan:
        idx.rescan()
    subjects = _subjects_json(request, db, idx) if subjects_too else b"[]"
    head = _dumps({"disk": layout.disk(), "data_dir": str(layout.data_dir)})
    tail = _dumps({"pending_node_deletions": hub.transfers.pending_deletions(),
                   "usage_scanned_at": None if idx.scanned_at is None else
                   datetime.fromtimestamp(idx.scanned_at, UTC).isoformat(timespec="seconds")})
    # the kept list goes in as it is: {head..., "subjects": [...], tail...}
    return Response(head[:-1] + b',"subjects":' + subjects + b"," + tail[1:],
                    media_type="application/json")


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
