"""Helpers shared by the data-management routes (projects, subjects, sessions, storage,
exports): lookups that answer 404 with a clear message, JSON views, deletion, the
storage layout and the background sync (started by the storage router's lifespan)."""

from __future__ import annotations

import asyncio
import hashlib
import json
from pathlib import Path
from typing import Any, TypeVar

from fastapi import HTTPException, Request, status
from sqlalchemy import func, select
from sqlalchemy.orm import Session as DbSession
from sqlalchemy.orm import selectinload

from app.api.routes._exporting import ExportGuard
from app.api.timestamps import utc_iso
from app.db import audit
from app.db import data as m
from app.db.base import purge_deleted
from app.db.models import AuditEvent, User
from app.server import erasures
from app.server.datasync import DataSync
from app.server.hub import Hub
from app.server.storage import StorageLayout

T = TypeVar("T")


def client_of(request: Request) -> str:
    """The requesting address (for the audit trail)."""
    return request.client.host if request.client else ""


def audit_event(request: Request, user: User, action: str, target: str,
                detail: str = "") -> AuditEvent:
    """An audit entry for ``user``'s request (add it to the session whose commit it
    records)."""
    return audit.event(user.username, action, target, detail, client_of(request))


def audit_now(db: DbSession, request: Request, user: User, action: str, target: str,
              detail: str = "") -> None:
    """Append an audit entry for ``user``'s request and commit it."""
    audit.record(db, user.username, action, target, detail, client_of(request))


def layout_of(request: Request) -> StorageLayout:
    """The server's storage layout."""
    return StorageLayout(request.app.state.settings.data_dir)


def datasync_of(request: Request) -> DataSync:
    """The running :class:`DataSync` (created on first use if the lifespan did not run)."""
    ds: DataSync | None = getattr(request.app.state, "datasync", None)
    if ds is None:
        ds = DataSync(request.app.state.hub, request.app.state.db_sessions, layout_of(request))
        request.app.state.datasync = ds
    return ds


def refusal(exc: BaseException, copy: Path, name: str, text: str | None = None) -> str:
    """Why the file ``name`` (read from ``copy``) was refused, naming it at most once:
    a reader's "cannot read walk.c3d as C3D: …" (or "cannot read walk.c3d: …",
    "walk.csv: …") becomes the Subjects page's "'walk.c3d' is not a readable C3D file:
    …", a reader's sentence that names the file ("Gang.trc is not a TRC file …") is
    kept as it is, and any other reason ("no steps were found") is returned without the
    file's name: the caller, seeing ``name not in`` it, names the file itself (prefixing
    every reason with the name said it twice: "'Gang.trc' is not a readable TRC file:
    Gang.trc is not a TRC file …", "trial 3.c3d: cannot read trial 3.c3d as C3D: …").
    ``text`` is said instead of ``str(exc)`` when given (the error's reason and advice in
    a page's words, :meth:`engine.errors.GaitrigError.words`)."""
    why = (str(exc) if text is None else text).replace(str(copy), name).replace(copy.name, name)
    kind = (Path(name).suffix or copy.suffix).lstrip(".").upper()
    for reader in (f"cannot read {name} as {kind}: ", f"cannot read {name}: ", f"{name}: "):
        if why.startswith(reader):
            return f"{name!r} is not a readable {kind} file: {why[len(reader):]}"
    return why


#: Largest integer id a row can have (SQL BIGINT). A larger one names no row, and the
#: database driver raises OverflowError on it (a 500), so lookups answer 404 first.
MAX_DB_ID = 2**63 - 1


def not_found(what: str) -> HTTPException:
    return HTTPException(status.HTTP_404_NOT_FOUND, what)


def get_row(db: DbSession, model: type[T], row_id: int) -> T | None:
    """``db.get`` that answers None for an id outside the database's integer range."""
    if not -MAX_DB_ID - 1 <= row_id <= MAX_DB_ID:
        return None
    return db.get(model, row_id)


def get_project(db: DbSession, pid: int) -> m.Project:
    p = get_row(db, m.Project, pid)
    if p is None:
        raise not_found(f"no project {pid}")
    return p


def get_subject(db: DbSession, sid: int) -> m.Subject:
    s = get_row(db, m.Subject, sid)
    if s is None:
        raise not_found(f"no subject {sid}")
    return s


#: Loader options that read a session's recordings with their parts and references in
#: three queries (one per table) instead of one query per session and per recording.
SESSION_TREE = (selectinload(m.Session.recordings).selectinload(m.Recording.parts),
                selectinload(m.Session.recordings).selectinload(m.Recording.references))


def get_subject_tree(db: DbSession, sid: int) -> m.Subject:
    """:func:`get_subject` with its sessions, recordings, parts and references loaded at
    once (four queries whatever their number)."""
    if not -MAX_DB_ID - 1 <= sid <= MAX_DB_ID:
        raise not_found(f"no subject {sid}")
    s = db.scalar(select(m.Subject).where(m.Subject.id == sid).options(
        *(selectinload(m.Subject.sessions).options(o) for o in SESSION_TREE)))
    if s is None:
        raise not_found(f"no subject {sid}")
    return s


def get_session(db: DbSession, sid: int) -> m.Session:
    s = get_row(db, m.Session, sid)
    if s is None:
        raise not_found(f"no session {sid}")
    return s


def get_recording(db: DbSession, rec_id: str) -> m.Recording:
    r = db.get(m.Recording, rec_id)
    if r is None:
        raise not_found(f"no recording {rec_id!r} in the database: it is not filed under a "
                        "session. File it on the Subjects page (\"Recordings not filed under a "
                        "session\") or with POST /api/sessions/{session_id}/recordings/attach "
                        "{\"rec_id\": …}, and start new ones from the Record page")
    return r


def check_confirm(expected: str, given: str | None, what: str) -> None:
    """Deletion needs the subject code (or project name) typed again."""
    if given is None or given.strip() != expected:
        raise HTTPException(status.HTTP_400_BAD_REQUEST,
                            f"to delete {what}, type {expected!r} exactly in the confirmation "
                            "field")


def part_json(p: m.RecordingPart) -> dict[str, Any]:
    return {"node_id": p.node_id, "state": p.state, "reason": p.reason,
            "n_frames": p.n_frames, "bytes_total": p.bytes_total, "bytes_done": p.bytes_done,
            "progress": round(p.progress, 4), "manifest_sha256": p.manifest_sha256,
            "attempts": p.attempts}


def recording_json(r: m.Recording, layout: StorageLayout | None = None) -> dict[str, Any]:
    d: dict[str, Any] = {
        "id": r.id, "session_id": r.session_id, "label": r.label, "notes": r.notes,
        "state": r.state, "reason": r.reason, "t_start": r.t_start, "t_stop": r.t_stop,
        "duration_s": r.duration_s, "streams": [s for s in r.streams.split(",") if s],
        "created_at": utc_iso(r.created_at), "parts": [part_json(p) for p in r.parts],
        "references": [reference_json(x) for x in r.references],
    }
    if layout is not None:
        d["bytes_on_server"] = layout.recording_bytes(r.id)
    return d


def reference_json(x: m.ReferenceImport) -> dict[str, Any]:
    return {"id": x.id, "filename": x.filename, "format": x.format, "size": x.size,
            "rate_hz": x.rate_hz, "n_frames": x.n_frames, "labels": x.labels,
            "created_at": utc_iso(x.created_at)}


def session_json(s: m.Session, layout: StorageLayout | None = None,
                 recordings: bool = True) -> dict[str, Any]:
    d: dict[str, Any] = {"id": s.id, "subject_id": s.subject_id, "date": s.date.isoformat(),
                         "label": s.label, "notes": s.notes,
                         "n_recordings": len(s.recordings)}
    if recordings:
        d["recordings"] = [recording_json(r, layout) for r in s.recordings]
    return d


def subject_json(s: m.Subject, layout: StorageLayout | None = None,
                 sessions: bool = False) -> dict[str, Any]:
    d: dict[str, Any] = {
        "id": s.id, "project_id": s.project_id, "code": s.code, "height_m": s.height_m,
        "leg_length_m": s.leg_length_m, "sex": s.sex, "birth_year": s.birth_year,
        "notes": s.notes, "n_sessions": len(s.sessions),
        "n_recordings": sum(len(x.recordings) for x in s.sessions),
        "version": subject_version(s),
    }
    if layout is not None:
        d["bytes_on_server"] = subject_bytes(s, layout)
    if sessions:
        d["sessions"] = [session_json(x, layout) for x in s.sessions]
    return d


def subject_list_json(s: m.Subject, n_sessions: int, n_recordings: int,
                      bytes_on_server: int | None) -> dict[str, Any]:
    """:func:`subject_json` (with the bytes on the server, None when not asked for) from
    counts the list query gave, without loading the subject's sessions and recordings."""
    return {"id": s.id, "project_id": s.project_id, "code": s.code, "height_m": s.height_m,
            "leg_length_m": s.leg_length_m, "sex": s.sex, "birth_year": s.birth_year,
            "notes": s.notes, "n_sessions": n_sessions, "n_recordings": n_recordings,
            "version": subject_version(s), "bytes_on_server": bytes_on_server}


def subject_version(s: m.Subject) -> str:
    """A digest of the subject's editable fields: an edit based on another version was
    made on a stale copy (another browser saved in between)."""
    fields = [s.code, s.height_m, s.leg_length_m, s.sex, s.birth_year, s.notes]
    return hashlib.sha256(json.dumps(fields).encode()).hexdigest()[:16]


def subject_bytes(s: m.Subject, layout: StorageLayout) -> int:
    return sum(layout.recording_bytes(r.id) for x in s.sessions for r in x.recordings)


def project_json(db: DbSession, p: m.Project, n_subjects: int | None = None) -> dict[str, Any]:
    """A project with its number of subjects (counted now unless given)."""
    n = n_subjects if n_subjects is not None else db.scalar(
        select(func.count()).select_from(m.Subject).where(m.Subject.project_id == p.id))
    return {"id": p.id, "name": p.name, "description": p.description, "n_subjects": n or 0,
            "created_at": utc_iso(p.created_at)}


async def delete_rows(db: DbSession, hub: Hub, layout: StorageLayout, exports: ExportGuard,
                      recs: list[m.Recording], owner: Any = None,
                      entry: AuditEvent | None = None) -> dict[str, list[str]]:
    """Delete recordings (and ``owner``, the session, subject or project that held them)
    everywhere: database rows, the server's files, live entries, the nodes' copies.

    Refused (409, nothing deleted) while one of them is recorded or transferred, or an
    export of their subject is being downloaded. Order,
    so that a crash or a concurrent transfer at any point leaves the database and the
    files consistent:

    1. in the event loop, with nothing awaited in between, the checks and the removal of
       the live entries: no transfer and no data-sync step can start between them, and
       a recording the backbone no longer knows is never transferred again;
    2. a tombstone naming the recordings is written, the rows are deleted and committed
       (with ``entry``, the audit trail's record); a failed commit drops the tombstone
       and puts the live entries back, every file is kept;
    3. the nodes are asked to delete their copies, the server's files go, the tombstone
       is cleared. A server that dies before this finishes it when it starts again
       (:func:`resume_deletions`).

    Returns:
        The deleted recordings and, for each, the nodes that hold (or held) a part.
    """
    for r in recs:
        live = hub.recordings.recordings.get(r.id)
        if live is not None and live.t_stop is None:
            raise HTTPException(status.HTTP_409_CONFLICT,
                                f"recording {r.id} is still running; stop it first")
        # the database mirrors the transfer state only twice a second: ask the transfers
        if r.state == "transferring" or hub.transfers.running_parts(r.id):
            raise HTTPException(status.HTTP_409_CONFLICT,
                                f"recording {r.id} is being transferred; wait until it ends")
    plan = {r.id: recording_nodes(hub, r) for r in recs}
    # refused while a subject's export streams (it would end cut short); no export
    # starts until the files are gone
    release = exports.start_deletion(_subject_ids(recs, owner))
    try:
        held = {k: hub.recordings.recordings.pop(k) for k in plan
                if k in hub.recordings.recordings}
        try:
            await asyncio.to_thread(_commit_deletion, db, layout, recs, owner, entry, plan)
        except BaseException:
            hub.recordings.recordings.update(held)  # the rows survived, so do their entries
            raise
        if held:
            hub.recordings.save()
        for rec_id, nodes in plan.items():
            # sent now or when a node reconnects (TransferManager.request_deletion)
            hub.transfers.request_deletion(rec_id, nodes)
        await asyncio.to_thread(_remove_files, db, layout, plan)
    finally:
        release()
    return plan


def _subject_ids(recs: list[m.Recording], owner: Any) -> set[int]:
    """The subjects a deletion takes data from (for the app's :class:`ExportGuard`)."""
    out = {r.session.subject_id for r in recs}
    if isinstance(owner, m.Subject):
        out.add(owner.id)
    elif isinstance(owner, m.Project):
        out.update(x.id for x in owner.subjects)
    return out


async def delete_unfiled(db: DbSession, hub: Hub, layout: StorageLayout, rec_id: str,
                         entry: AuditEvent | None = None) -> list[str]:
    """Delete a recording filed under no session (started from the Rig page): the
    server's files, its live entry and the nodes' copies, in the order of
    :func:`delete_rows` (tombstone, commit of the audit entry, files).

    Returns:
        The nodes that hold (or held) a part of it.

    Raises:
        HTTPException: 404 unknown; 409 filed under a session, running or transferring.
    """
    live = hub.recordings.recordings.get(rec_id)
    if live is None:
        raise not_found(f"no recording {rec_id!r} on the server")
    if db.get(m.Recording, rec_id) is not None:
        raise HTTPException(status.HTTP_409_CONFLICT,
                            f"recording {rec_id} is filed under a session; delete it from its "
                            "subject on the Subjects page")
    if live.t_stop is None:
        raise HTTPException(status.HTTP_409_CONFLICT,
                            f"recording {rec_id} is still running; stop it first")
    if live.state == "transferring" or hub.transfers.running_parts(rec_id):
        raise HTTPException(status.HTTP_409_CONFLICT,
                            f"recording {rec_id} is being transferred; wait until it ends")
    plan = {rec_id: sorted(live.parts)}
    hub.recordings.recordings.pop(rec_id)  # in the loop, right after the checks
    try:
        await asyncio.to_thread(_commit_deletion, db, layout, [], None, entry, plan)
    except BaseException:
        hub.recordings.recordings[rec_id] = live
        raise
    hub.recordings.save()
    hub.transfers.request_deletion(rec_id, plan[rec_id])
    await asyncio.to_thread(_remove_files, db, layout, plan)
    return plan[rec_id]


NODE_DELETE_WAIT_S = 5.0  # a deletion's answer waits this long for the nodes' copies


async def node_copies(hub: Hub, plan: dict[str, list[str]]) -> dict[str, str]:
    """Ask the connected nodes to delete their copies now, wait briefly, and say per
    node ``deleted`` or why not yet (e.g. ``node offline: deleted when it reconnects``)."""
    started = hub.transfers.flush_deletions()
    if started:
        await asyncio.wait(started, timeout=NODE_DELETE_WAIT_S)
    out: dict[str, str] = {}
    for rec_id, nodes in plan.items():
        for node, st in hub.transfers.deletion_status(rec_id, nodes).items():
            if out.get(node, "deleted") == "deleted":
                out[node] = st
    return dict(sorted(out.items()))


def _commit_deletion(db: DbSession, layout: StorageLayout, recs: list[m.Recording],
                     owner: Any, entry: AuditEvent | None, plan: dict[str, list[str]]) -> None:
    layout.add_tombstones(plan)
    # kept for good, so that restoring an older backup deletes this again (docs/backup.md)
    eid = erasures.begin(layout.data_dir, recs, owner, plan)
    try:
        for r in recs:
            db.delete(r)
        if owner is not None:
            db.delete(owner)
        if entry is not None:
            db.add(entry)
        db.commit()
    except BaseException:
        db.rollback()
        layout.drop_tombstones(plan)
        erasures.finish(layout.data_dir, eid, committed=False)
        raise
    erasures.finish(layout.data_dir, eid, committed=True)


def _remove_files(db: DbSession, layout: StorageLayout, plan: dict[str, list[str]]) -> None:
    for rec_id in plan:
        layout.delete_recording(rec_id)
    layout.drop_tombstones(plan)
    purge(db)


def finish_deletions(hub: Hub, layout: StorageLayout, plan: dict[str, list[str]]) -> None:
    """Everything of a deletion after its rows are gone (at start-up, for one the last
    run did not finish): live entries, the nodes' copies, the server's files, the
    tombstones."""
    popped = [hub.recordings.recordings.pop(k, None) for k in plan]
    if any(x is not None for x in popped):
        hub.recordings.save()
    for rec_id, nodes in plan.items():
        hub.transfers.request_deletion(rec_id, nodes)
        layout.delete_recording(rec_id)
    layout.drop_tombstones(plan)


def resume_deletions(db: DbSession, hub: Hub, layout: StorageLayout) -> list[str]:
    """Finish the deletions a stopped server left half done (at start-up).

    A tombstoned recording whose row still exists was not deleted (the commit never
    happened): its tombstone is dropped. One whose row is gone loses its files now.

    Returns:
        The recordings whose deletion was finished.
    """
    erasures.settle(db, layout.data_dir)  # a deletion logged but cut short by a crash
    stones = layout.tombstones()
    if not stones:
        return []
    alive = set(db.scalars(select(m.Recording.id).where(m.Recording.id.in_(list(stones)))))
    todo = {k: sorted(set(v) | set(getattr(hub.recordings.recordings.get(k), "parts", {})))
            for k, v in stones.items() if k not in alive}
    finish_deletions(hub, layout, todo)
    layout.drop_tombstones(stones)
    if todo:
        purge(db)
    return sorted(todo)


def purge(db: DbSession) -> None:
    """After a deletion committed: no copy of the deleted rows left in the database
    files (SQLite's write-ahead log; see :func:`app.db.base.purge_deleted`)."""
    purge_deleted(db.get_bind().engine)


def recording_nodes(hub: Hub, r: m.Recording) -> list[str]:
    """Nodes that hold (or held) a part of a recording."""
    live = hub.recordings.recordings.get(r.id)
    return sorted({p.node_id for p in r.parts} | set(live.parts if live is not None else ()))
