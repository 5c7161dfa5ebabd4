"""Sessions (visits) of a subject, and the recordings made in them.

``POST /api/sessions/{id}/recordings`` starts a synchronous recording on every connected
node (the backbone's :meth:`RecordingManager.start`) and files it under the session; after
it is stopped (``POST /api/recordings/{rec_id}/stop``) the server transfers every node's
part on its own (:mod:`app.server.datasync`).
"""

from __future__ import annotations

import datetime as dt
from typing import Any, Literal

from fastapi import APIRouter, HTTPException, Request, status
from pydantic import BaseModel, Field
from sqlalchemy import select
from sqlalchemy.exc import IntegrityError

from app.api.deps import CurrentUser, DbDep, ExportsDep, HubDep
from app.api.limits import BoundedRoute
from app.api.routes._data import (
    audit_event,
    check_confirm,
    datasync_of,
    delete_rows,
    get_session,
    get_subject,
    get_subject_tree,
    layout_of,
    node_copies,
    purge,
    recording_json,
    session_json,
)
from app.db import data as m
from engine.errors import InputError
from engine.wording import count

router = APIRouter(prefix="/sessions", route_class=BoundedRoute, tags=["data"])


class SessionIn(BaseModel):
    subject_id: int
    date: dt.date = Field(default_factory=dt.date.today)
    label: str = Field(default="", max_length=120, description="e.g. baseline, 6 weeks")
    notes: str = Field(default="", max_length=4000)


class SessionPatch(BaseModel):
    date: dt.date | None = None
    label: str | None = Field(default=None, max_length=120)
    notes: str | None = Field(default=None, max_length=4000)


class RecordIn(BaseModel):
    label: str = Field(default="", max_length=120, description="e.g. walk 1")
    # at most the three streams: the list is stored joined in a 120-character column
    streams: list[Literal["depth", "color", "body_index"]] = Field(default_factory=list,
                                                                   max_length=3)
    image_every: int = Field(default=1, ge=1, le=1000)


class AttachIn(BaseModel):
    rec_id: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")
    label: str = Field(default="", max_length=120)


class Confirm(BaseModel):
    confirm: str = Field(max_length=200, description="The subject code typed again.")


@router.get("")
def list_sessions(request: Request, user: CurrentUser, db: DbDep,
                  subject_id: int) -> list[dict[str, Any]]:
    """Sessions of a subject, with their recordings (four queries whatever their
    number: the subject, its sessions, their recordings, parts and references)."""
    s = get_subject_tree(db, subject_id)
    layout = layout_of(request)
    return [session_json(x, layout) for x in s.sessions]


@router.post("", status_code=201)
def create_session(body: SessionIn, user: CurrentUser, db: DbDep) -> dict[str, Any]:
    """Open a session for a subject."""
    get_subject(db, body.subject_id)
    s = m.Session(subject_id=body.subject_id, date=body.date, label=body.label.strip(),
                  notes=body.notes)
    db.add(s)
    db.commit()
    return session_json(s)


@router.get("/{sid}")
def get_one(sid: int, request: Request, user: CurrentUser, db: DbDep) -> dict[str, Any]:
    """A session with its recordings."""
    return session_json(get_session(db, sid), layout_of(request))


@router.patch("/{sid}")
def update_session(sid: int, body: SessionPatch, user: CurrentUser, db: DbDep
                   ) -> dict[str, Any]:
    """Change a session's date, label or notes."""
    s = get_session(db, sid)
    for k, v in body.model_dump(exclude_unset=True).items():
        if v is not None:
            setattr(s, k, v)
    db.commit()
    purge(db)  # an edited note leaves no copy of the old text in the database files
    return session_json(s)


@router.post("/{sid}/delete")
async def delete_session(sid: int, body: Confirm, request: Request, user: CurrentUser, db: DbDep,
                   hub: HubDep, exports: ExportsDep) -> dict[str, Any]:
    """Delete a session with its recordings and their files (confirm = subject code)."""
    s = get_session(db, sid)
    check_confirm(s.subject.code, body.confirm,
                  f"this session of {s.subject.code} and its recordings")
    plan = await delete_rows(db, hub, layout_of(request), exports, list(s.recordings), s,
                             audit_event(request, user, "delete", f"session {sid}",
                                         f"subject {s.subject_id}; "
                                         f"{count(len(s.recordings), 'recording')}"))
    return {"deleted": "session", "id": sid, "recordings_deleted": len(plan),
            "node_copies": await node_copies(hub, plan)}


@router.post("/{sid}/recordings", status_code=201)
async def start_recording(sid: int, body: RecordIn, request: Request, user: CurrentUser, db: DbDep,
                    hub: HubDep) -> dict[str, Any]:
    """Start a recording on every connected node, filed under this session.

    Refused (409) while another recording runs or when no node is ready.
    """
    s = get_session(db, sid)
    try:
        rec = hub.recordings.start(list(body.streams), body.image_every)
    except InputError as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from exc
    row = m.Recording(id=rec.id, session_id=s.id, label=body.label.strip(),
                      streams=",".join(body.streams), state="recording", t_start=rec.t_start)
    db.add(row)
    datasync_of(request).write(db, row, rec)
    try:
        db.commit()
    except IntegrityError as exc:  # the session was deleted while the recording started
        db.rollback()
        hub.recordings.stop(rec.id)
        raise HTTPException(status.HTTP_409_CONFLICT,
                            f"session {sid} was deleted while recording {rec.id} started; the "
                            "recording was stopped and is listed as not filed under a "
                            "session (file it under a session to keep or to delete it)") from exc
    return recording_json(row)


@router.post("/{sid}/recordings/attach", status_code=201)
async def attach_recording(sid: int, body: AttachIn, request: Request, user: CurrentUser, db: DbDep,
                     hub: HubDep) -> dict[str, Any]:
    """File a recording started elsewhere (e.g. ``POST /api/recordings``) under a session."""
    s = get_session(db, sid)
    rec = hub.recordings.recordings.get(body.rec_id)
    if rec is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no recording {body.rec_id!r}")
    if db.scalar(select(m.Recording).where(m.Recording.id == rec.id)) is not None:
        raise HTTPException(status.HTTP_409_CONFLICT,
                            f"recording {rec.id} already belongs to a session")
    row = m.Recording(id=rec.id, session_id=s.id, label=body.label.strip(),
                      streams=",".join(rec.streams), state="recording", t_start=rec.t_start)
    db.add(row)
    datasync_of(request).write(db, row, rec)
    db.commit()
    return recording_json(row, layout_of(request))
