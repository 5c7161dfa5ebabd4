"""Pseudonymised subjects of a project (code, height, leg length, sex, birth year, notes).

Lengths are metres in the API (the console shows cm). No names: the code is chosen by
the clinic and unique within a project.
"""

from __future__ import annotations

import datetime as dt
import functools
import logging
import re
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Literal

from fastapi import APIRouter, HTTPException, Request, Response, status
from fastapi.responses import StreamingResponse
from pydantic import BaseModel, Field
from sqlalchemy import func, select

from app.api.deps import CurrentUser, DbDep, ExportsDep, HubDep
from app.api.limits import BoundedRoute
from app.api.routes._data import (
    audit_event,
    audit_now,
    check_confirm,
    delete_rows,
    get_project,
    get_subject,
    get_subject_tree,
    layout_of,
    node_copies,
    purge,
    subject_json,
    subject_list_json,
    subject_version,
)
from app.api.routes._paging import (
    MAX_OFFSET,
    LimitQ,
    OffsetQ,
    like_pattern,
    page_of,
    set_total,
)
from app.api.routes.reports import (
    SubjectReportSource,
    build_subject_report,
    subject_report_source,
)
from app.db import data as m
from app.server.storage import (
    ExportEntry,
    StorageLayout,
    live_poses,
    stream_zip,
    subject_export,
)
from engine.errors import GaitrigError
from engine.report.render import render_pdf
from engine.wording import count

log = logging.getLogger(__name__)

router = APIRouter(prefix="/subjects", route_class=BoundedRoute, tags=["data"])

Sex = Literal["female", "male", "other", "unknown"]
CODE_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,39}$"


def _year_ok(y: int | None) -> int | None:
    if y is not None and not 1900 <= y <= dt.date.today().year:
        raise HTTPException(422,
                            f"birth_year {y} must be between 1900 and {dt.date.today().year}")
    return y


class SubjectIn(BaseModel):
    project_id: int
    code: str = Field(pattern=CODE_PATTERN, description="Pseudonym, e.g. P017 (no names).")
    height_m: float | None = Field(default=None, ge=0.4, le=2.6)
    leg_length_m: float | None = Field(default=None, ge=0.2, le=1.5)
    sex: Sex = "unknown"
    birth_year: int | None = None
    notes: str = Field(default="", max_length=4000)


class SubjectPatch(BaseModel):
    version: str | None = Field(default=None, max_length=64, description=(
        "The subject's 'version' the edit is based on: refused (409) if someone saved "
        "another change since."))
    code: str | None = Field(default=None, pattern=CODE_PATTERN)
    height_m: float | None = Field(default=None, ge=0.4, le=2.6)
    leg_length_m: float | None = Field(default=None, ge=0.2, le=1.5)
    sex: Sex | None = None
    birth_year: int | None = None
    notes: str | None = Field(default=None, max_length=4000)


class Confirm(BaseModel):
    confirm: str = Field(max_length=200, description="The subject code typed again.")


def _code_free(db: DbDep, project_id: int, code: str) -> None:
    if db.scalar(select(m.Subject).where(m.Subject.project_id == project_id,
                                         m.Subject.code == code)) is not None:
        raise HTTPException(status.HTTP_409_CONFLICT,
                            f"subject code {code!r} is already used in this project")


#: Subjects per page of ``GET /api/subjects``: by default, and at most.
SUBJECTS_PAGE, SUBJECTS_PAGE_MAX = 100, 500
SubjectSort = Literal["code", "-code", "created", "-created"]
_SUBJECT_ORDER = {"code": (m.Subject.code, m.Subject.id),
                  "-code": (m.Subject.code.desc(), m.Subject.id.desc()),
                  "created": (m.Subject.created_at, m.Subject.id),
                  "-created": (m.Subject.created_at.desc(), m.Subject.id.desc())}


class SubjectSearch(BaseModel):
    """A page of subjects, as the query of ``GET /api/subjects`` plus the search text
    (in the body: a subject code must not reach the access logs in a URL)."""

    q: str = Field(default="", max_length=100, description=(
        "Part of the code (case-insensitive); empty: every subject."))
    project_id: int | None = None
    sort: SubjectSort = "code"
    limit: int | None = Field(default=None, ge=1)
    offset: int = Field(default=0, ge=0, le=MAX_OFFSET)
    bytes_on_server: bool = Field(default=True, description=(
        "false: leave out the bytes on the server (null), which read every listed "
        "subject's recording folders"))


@router.get("")
def list_subjects(request: Request, response: Response, user: CurrentUser, db: DbDep,
                  project_id: int | None = None, sort: SubjectSort = "code",
                  limit: LimitQ = None, offset: OffsetQ = 0,
                  bytes_on_server: bool = True) -> list[dict[str, Any]]:
    """Subjects (of one project if ``project_id`` is given) with disk usage, a page at a
    time (``limit`` ≤ 500, default 100; ``offset``; the ``X-Total-Count`` header gives
    the number matching), ``sort`` by ``code`` or ``created`` (``-`` for descending).
    ``bytes_on_server=false`` leaves the disk usage out (null): it reads the page's
    recording folders, which a list of codes does not need. Searching a code:
    ``POST /api/subjects/search``.
    """
    if "q" in request.query_params:
        raise HTTPException(status.HTTP_400_BAD_REQUEST,
                            "search subjects with POST /api/subjects/search {\"q\": ...}: a "
                            "code in the URL would be kept in access logs")
    return _subjects_page(request, response, db, SubjectSearch(
        project_id=project_id, sort=sort, limit=limit, offset=offset,
        bytes_on_server=bytes_on_server))


@router.post("/search")
def search_subjects(body: SubjectSearch, request: Request, response: Response,
                    user: CurrentUser, db: DbDep) -> list[dict[str, Any]]:
    """A page of the subjects whose code contains ``q`` (case-insensitive), as
    ``GET /api/subjects`` answers it (``X-Total-Count``: how many match)."""
    return _subjects_page(request, response, db, body)


def _subjects_page(request: Request, response: Response, db: DbDep, f: SubjectSearch
                   ) -> list[dict[str, Any]]:
    """Three queries whatever the number of subjects: the count, the page with each
    subject's numbers of sessions and recordings, and the page's recording ids (for the
    bytes on the server, summed from the page's recording folders only; none without
    ``bytes_on_server``)."""
    page = page_of(f.limit, f.offset, SUBJECTS_PAGE, SUBJECTS_PAGE_MAX)
    where = []
    if f.project_id is not None:
        get_project(db, f.project_id)
        where.append(m.Subject.project_id == f.project_id)
    if f.q.strip():
        where.append(m.Subject.code.ilike(like_pattern(f.q.strip()), escape="\\"))
    set_total(response, db.scalar(select(func.count(m.Subject.id)).where(*where)) or 0)
    n_sess = (select(func.count(m.Session.id)).where(m.Session.subject_id == m.Subject.id)
              .correlate(m.Subject).scalar_subquery())
    n_rec = (select(func.count(m.Recording.id))
             .join(m.Session, m.Recording.session_id == m.Session.id)
             .where(m.Session.subject_id == m.Subject.id)
             .correlate(m.Subject).scalar_subquery())
    # the page's ids first: the counts are then computed for the page only (SQLite
    # would compute them for every subject before an ORDER BY it has no index for)
    ids = (select(m.Subject.id).where(*where).order_by(*_SUBJECT_ORDER[f.sort])
           .limit(page.limit).offset(page.offset).scalar_subquery())
    rows = db.execute(select(m.Subject, n_sess, n_rec).where(m.Subject.id.in_(ids))
                      .order_by(*_SUBJECT_ORDER[f.sort])).all()
    recs: dict[int, list[str]] = {}
    if rows and f.bytes_on_server:
        for sid, rec_id in db.execute(
                select(m.Session.subject_id, m.Recording.id)
                .join(m.Recording, m.Recording.session_id == m.Session.id)
                .where(m.Session.subject_id.in_([s.id for s, _, _ in rows]))):
            recs.setdefault(sid, []).append(rec_id)
    layout = layout_of(request)
    return [subject_list_json(s, ns or 0, nr or 0,
                              sum(layout.recording_bytes(r) for r in recs.get(s.id, ()))
                              if f.bytes_on_server else None)
            for s, ns, nr in rows]


@router.post("", status_code=201)
def create_subject(body: SubjectIn, request: Request, user: CurrentUser,
                   db: DbDep) -> dict[str, Any]:
    """Add a subject to a project."""
    get_project(db, body.project_id)
    _code_free(db, body.project_id, body.code)
    s = m.Subject(project_id=body.project_id, code=body.code, height_m=body.height_m,
                  leg_length_m=body.leg_length_m, sex=body.sex,
                  birth_year=_year_ok(body.birth_year), notes=body.notes)
    db.add(s)
    db.commit()
    return subject_json(s, layout_of(request))


@router.get("/{sid}")
def get_one(sid: int, request: Request, user: CurrentUser, db: DbDep) -> dict[str, Any]:
    """A subject with its sessions and their recordings (states, parts, progress)."""
    return subject_json(get_subject_tree(db, sid), layout_of(request), sessions=True)


def _report_pdf(src: SubjectReportSource, name: str, data_dir: Path, live: dict[str, Any],
                notes: list[str]) -> bytes | None:
    """One report of the export, rendered when its turn in the stream comes; a report
    that cannot be made is left out with a note (the archive must stay whole)."""
    try:
        return render_pdf(build_subject_report(src, data_dir, live))
    except GaitrigError as exc:
        notes.append(f"{name}: not included ({exc})")
    except Exception:  # any bug of the report must not cut the whole export short
        log.exception("export: the report %s of subject %s failed", name, src.subject_id)
        notes.append(f"{name}: not included (the report could not be rendered: an error "
                     "of the server, its log says which)")
    return None


def _report_entries(db: DbDep, s: m.Subject, data_dir: Path, live: dict[str, Any]
                    ) -> Callable[[list[str]], Iterator[ExportEntry]]:
    """The subject's reports for its export: one per session and, with several
    sessions, one of all. What they need from the database is read now."""
    sources = [(f"reports/gait-report-session-{x.id}-{x.date}.pdf",
                subject_report_source(db, data_dir, s, x)) for x in s.sessions]
    if len(sources) > 1:
        sources.append(("reports/gait-report-all-sessions.pdf",
                        subject_report_source(db, data_dir, s)))

    def entries(notes: list[str]) -> Iterator[ExportEntry]:
        if not sources:
            notes.append("reports: none (the subject has no session)")
        for name, src in sources:
            yield name, functools.partial(_report_pdf, src, name, data_dir, live, notes)

    return entries


@router.get("/{sid}/export", response_class=StreamingResponse)
def export_subject(sid: int, request: Request, user: CurrentUser, db: DbDep,
                   hub: HubDep, exports: ExportsDep) -> StreamingResponse:
    """Everything held about a subject as one zip (right of access, data portability).

    ``subject.json`` (the subject, project, sessions, recordings, references), every
    recording's files as stored (node parts byte-identical, sensor poses, analyses, the
    reports' reference), each part's skeleton as CSV, the uploaded references,
    the subject's gait reports as PDF (``reports/``, rendered now) and a ``README.txt``
    describing the formats. Streamed piece by piece: the server never holds the archive
    (or a file of it, but for one report or skeleton CSV at a time) in memory or on disk.

    While the download runs, deleting the subject (or a session, recording or project
    of it) is refused (409) instead of cutting the archive short
    (:mod:`app.api.routes._exporting`).
    """
    layout = layout_of(request)
    # claimed before anything is read: a deletion that ended before this is seen whole
    release = exports.start_export(sid)
    try:
        db.rollback()  # no read transaction older than the claim
        response = _export_response(sid, request, user, db, hub, layout, release)
    except BaseException:
        release()
        raise
    return response


class _ReleasingStream(StreamingResponse):
    """A streamed response that releases its export claim when sending ends: done,
    failed, or the client went away (the stream is then cancelled)."""

    def __init__(self, content: Iterator[bytes], release: Callable[[], None],
                 **kwargs: Any) -> None:
        super().__init__(content, **kwargs)
        self._release = release

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        try:
            await super().__call__(scope, receive, send)
        finally:
            self._release()


def _export_response(sid: int, request: Request, user: Any, db: DbDep, hub: HubDep,
                     layout: StorageLayout, release: Callable[[], None]) -> StreamingResponse:
    s = get_subject(db, sid)
    info = subject_json(s, layout, sessions=True)
    info["project"] = {"id": s.project.id, "name": s.project.name}
    info["exported_at"] = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    info["format"] = "gaitrig subject export 1 (see README.txt)"
    rec_ids = [r.id for x in s.sessions for r in x.recordings]
    # read everything from the database now: the stream runs after this session closed
    live = live_poses(layout, hub.registry)
    entries = subject_export(layout, info, rec_ids, live,
                             _report_entries(db, s, layout.data_dir, live))
    audit_now(db, request, user, "export", f"subject {sid}",
              f"zip of {count(len(rec_ids), 'recording')} with reports")
    code = re.sub(r"[^A-Za-z0-9_.-]", "_", s.code)  # the pattern's, even for an old row
    name = f"gaitrig-subject-{code}-{dt.date.today().isoformat()}.zip"
    return _ReleasingStream(stream_zip(entries), release, media_type="application/zip",
                            headers={"Content-Disposition": f'attachment; filename="{name}"'})


@router.patch("/{sid}")
def update_subject(sid: int, body: SubjectPatch, request: Request, user: CurrentUser,
                   db: DbDep) -> dict[str, Any]:
    """Change a subject's fields (only those given)."""
    s = get_subject(db, sid)
    fields = body.model_dump(exclude_unset=True)
    seen = fields.pop("version", None)
    if seen is not None and seen != subject_version(s):
        raise HTTPException(status.HTTP_409_CONFLICT,
                            f"subject {s.code} was changed by someone else since you opened "
                            "it; reload to see their change, then make yours again")
    if "code" in fields and fields["code"] != s.code:
        _code_free(db, s.project_id, fields["code"])
    if "birth_year" in fields:
        _year_ok(fields["birth_year"])
    if "sex" in fields and fields["sex"] is None:
        fields["sex"] = "unknown"
    for k, v in fields.items():
        setattr(s, k, v if k != "notes" or v is not None else "")
    db.commit()
    purge(db)  # notes edited to remove a name: the old text leaves the database files too
    return subject_json(s, layout_of(request))


@router.post("/{sid}/delete")
async def delete_subject(sid: int, body: Confirm, request: Request, user: CurrentUser, db: DbDep,
                   hub: HubDep, exports: ExportsDep) -> dict[str, Any]:
    """Delete a subject, its sessions, recordings and their files on the server.

    The body must repeat the subject code (``{"confirm": "<code>"}``).
    """
    s = get_subject(db, sid)
    check_confirm(s.code, body.confirm, f"subject {s.code} and all its recordings")
    recs = [r for x in s.sessions for r in x.recordings]
    # the trail names the subject by its id only: it must not keep a deleted pseudonym
    plan = await delete_rows(db, hub, layout_of(request), exports, recs, s, audit_event(
        request, user, "delete", f"subject {sid}",
        f"project {s.project_id}; {count(len(s.sessions), 'session')}, "
        f"{count(len(recs), 'recording')}"))
    return {"deleted": "subject", "id": sid, "recordings_deleted": len(plan),
            "node_copies": await node_copies(hub, plan)}
