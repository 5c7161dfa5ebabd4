"""Gait analysis of recordings and gait reports (console HTML fragment and PDF download).

Routes (all under ``/api/reports``, login required):

* ``GET  /recordings`` — recordings with data on the server, their sensors and subject;
* ``GET  /recordings/{rec_id}/sensors`` — the recording's sensors, their positions and
  which side of the walkway they stand on (for one- vs two-sided analysis);
* ``GET  /recordings/{rec_id}/analysis`` — gait analysis JSON (``sensors=S1,S3`` for a
  subset, ``method``, ``estimator``);
* ``GET  /recordings/{rec_id}/compare`` — the same recording analysed with two sensor
  subsets (``a``, ``b``), e.g. one side against both sides;
* ``GET  /recordings/{rec_id}/report`` — report of one recording (``format=html|pdf``);
* ``GET/POST/DELETE /recordings/{rec_id}/reference`` — a reference recording (C3D, TRC
  or skeleton CSV) for the agreement section;
* ``GET  /subjects/{subject_id}`` — report of a subject from all its complete recordings,
  of some of its sessions (``sessions=3,5``: with two or more, the report adds the
  section "Change over sessions"), or of one session (``session_id``);
* ``GET  /projects/{project_id}/agreement`` — agreement with a reference system over a
  project's subjects (seed 000's Tables 1–3; ``format=html|pdf|csv|json``, ``sensors``,
  ``method``, ``estimator``) from its recordings with a reference attached;
* ``POST /upload`` — report of an uploaded C3D/TRC/CSV file (research engineers); the
  subject code printed on it is a form field (never in the URL).

Heavy work (fusion, gait, PDF) runs in FastAPI's thread pool (plain ``def`` routes).
"""

from __future__ import annotations

import asyncio
import datetime as _dt
import json
import os
import re
import secrets
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, NamedTuple

import numpy as np
from fastapi import APIRouter, Form, HTTPException, Query, Request, UploadFile, status
from fastapi.responses import HTMLResponse, Response
from sqlalchemy import select

from app.api.deps import CurrentUser, DbDep, HubDep, SettingsDep
from app.api.limits import BoundedRoute, refused_with
from app.api.routes import _reference
from app.api.routes._data import audit_now, get_row, refusal
from app.api.routes._paging import LimitQ, OffsetQ, SearchQ, like_pattern, page_of, set_total
from app.api.routes._reference import (
    OPTION_NAMES,
    check_reference,
    receive,
    reference_type,
    upload_name,
)
from app.db.data import Project, ReferenceImport, Subject
from app.db.data import Recording as DbRecording
from app.db.data import Session as DbSession
from app.server import analysis as an
from app.server import erasures
from app.server.storage import note_changed
from engine.errors import GaitrigError, InputError, InsufficientDataError
from engine.report.progress import SessionTrials
from engine.report.render import ReportData, render_html, render_pdf
from engine.wording import count

if TYPE_CHECKING:  # the study's module imports scipy: loaded on a study's first request
    from engine.report.study import StudyReport

router = APIRouter(prefix="/reports", route_class=BoundedRoute, tags=["reports"])

#: Largest accepted request of an upload (a reference, or "Analyse a file"): the limit of
#: a reference file on either page (app.api.routes._reference) and the multipart around it.
_UPLOAD_BODY_MAX = _reference.MAX_REFERENCE_BYTES + _reference.UPLOAD_OVERHEAD
_SENSOR_RE = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
_STORED_RE = re.compile(r"^[0-9a-f]{8,64}\.(c3d|trc|csv)$")

Fmt = Literal["html", "pdf"]
MethodQ = Literal["crossing", "heelstrike"]
EstimatorQ = Literal["weighted", "mean"]


# ---------------------------------------------------------------------------- helpers


def _rec_dir(settings: Any, rec_id: str, hub: Any) -> Path:
    try:
        d = an.recording_dir(settings.data_dir, rec_id)
    except InputError as exc:
        raise HTTPException(status.HTTP_400_BAD_REQUEST, str(exc)) from exc
    if not d.exists() and rec_id not in hub.recordings.recordings:
        # (a mistyped id was told to transfer a recording that does not exist)
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"no recording {rec_id!r}: check its id (the Subjects page lists "
                            "every recording)")
    if not an.part_dirs(d):
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"recording {rec_id} has no sensor data on the server; transfer "
                            "it from the nodes first (Subjects page)")
    return d


def _sensors_param(value: str | None) -> tuple[str, ...] | None:
    """``"S1,S3"`` → ``("S1", "S3")``; empty or ``all`` → None (every sensor)."""
    if value is None or value.strip() in ("", "all"):
        return None
    out = tuple(dict.fromkeys(s.strip() for s in value.split(",") if s.strip()))
    for s in out:
        if not _SENSOR_RE.match(s):
            raise HTTPException(status.HTTP_400_BAD_REQUEST,
                                f"sensor id {s!r} must be 1-64 characters of A-Z a-z 0-9 _ . -")
    return out


def _live_poses(hub: Any) -> dict[str, Any]:
    """Sensor poses known now: the active calibration's, else the nodes' reported poses."""
    from app.server.calibration import active_poses

    out: dict[str, Any] = dict(active_poses(hub.settings.data_dir))
    for node_id, s in hub.registry.nodes.items():
        T = s.sensor.T_world_sensor
        if T is not None and node_id not in out:
            out[node_id] = {"T_world_sensor": T, "source": "node"}
    return out


def _analyse(settings: Any, hub: Any, rec_id: str, sensors: tuple[str, ...] | None,
             method: str, estimator: str) -> dict[str, Any]:
    d = _rec_dir(settings, rec_id, hub)
    try:
        return an.analyse_recording(d, an.AnalysisOptions(method, estimator, sensors),
                                    _live_poses(hub))
    except InsufficientDataError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from exc
    except InputError as exc:
        raise HTTPException(status.HTTP_400_BAD_REQUEST, str(exc)) from exc
    except GaitrigError as exc:  # any other typed engine failure: the data, not the server
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from exc


def _filename(*parts: str) -> str:
    stem = "-".join(re.sub(r"[^A-Za-z0-9_.-]+", "_", p).strip("_.") for p in parts if p)
    return (stem or "report")[:120]


def _respond(data: ReportData, fmt: str, name: str) -> Response:
    try:
        if fmt == "pdf":
            pdf = render_pdf(data)
            return Response(pdf, media_type="application/pdf", headers={
                "Content-Disposition": f'attachment; filename="{_filename(name)}.pdf"'})
        return HTMLResponse(render_html(data, standalone=False))
    except GaitrigError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from exc


def _reference_file(rec_dir: Path) -> tuple[Path, dict[str, Any]] | None:
    folder = rec_dir / "reference"
    meta_path = folder / "meta.json"
    if not meta_path.is_file():
        return None
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    f = folder / f"reference{meta.get('ext', '')}"
    return (f, meta) if f.is_file() else None


class ReferenceFile(NamedTuple):
    """A recording's reference file for its report."""

    path: Path  # the server's copy
    offset_s: float  # s into the recording at which the reference starts (added to its times)
    name: str  # as the person chose it ("vicon walk.c3d"), for messages


def _reference_paths(db: Any, data_dir: Path, rec_dirs: dict[str, Path]
                     ) -> dict[str, ReferenceFile]:
    """rec_id → its reference file, the time into the recording at which it starts and the
    file's name as uploaded.

    A reference attached on this page wins; otherwise the newest one imported on the
    Subjects page (data-management ``ReferenceImport``, assumed to start with the
    recording).
    """
    out: dict[str, ReferenceFile] = {}
    for rec_id, d in rec_dirs.items():
        ref = _reference_file(d)
        if ref is not None:
            out[rec_id] = ReferenceFile(ref[0], float(ref[1].get("offset_s") or 0.0),
                                        str(ref[1].get("filename") or "") or ref[0].name)
            continue
        imp = db.scalars(select(ReferenceImport)
                         .where(ReferenceImport.recording_id == rec_id)
                         .order_by(ReferenceImport.created_at.desc())).first()
        if imp is None or not _STORED_RE.match(imp.stored_name):
            continue
        path = Path(data_dir) / "references" / rec_id / imp.stored_name
        if path.is_file():
            out[rec_id] = ReferenceFile(path, 0.0, imp.filename or path.name)
    return out


def _reference_steps(paths: dict[str, ReferenceFile], method: str,
                     labels: dict[str, str] | None = None
                     ) -> tuple[dict[str, list[dict[str, Any]]], list[str]]:
    """rec_id → reference steps on the recording's time axis, and notes on failures
    (naming each recording by its trial label in ``labels``, rec_id → label, and its
    reference file once, as the person chose it: "the reference could not be used —
    'vicon walk.c3d' is not a readable C3D file: …", "the reference vicon walk.c3d could
    not be used — no steps were found"; was "the reference could not be used — reference
    reference.c3d: cannot read reference.c3d as C3D: …", the server's name twice)."""
    out: dict[str, list[dict[str, Any]]] = {}
    notes: list[str] = []
    for rec_id, (path, off, name) in paths.items():
        try:
            steps = an.reference_steps(path, method)
        except GaitrigError as exc:
            notes.append(_reference_refused(
                an.recording_named(rec_id, (labels or {}).get(rec_id, "")), exc, path, name))
            continue
        out[rec_id] = [{**s, "time_s": s["time_s"] + off} for s in steps]
    return out, notes


def _reference_refused(trial: str, exc: BaseException, path: Path, name: str) -> str:
    """A report's note on a reference that gave no steps, naming the trial and the file
    once (:func:`app.api.routes._data.refusal`)."""
    why = refusal(exc, path, name)
    return (f"{trial}: the reference could not be used — {why}" if name in why
            else f"{trial}: the reference {name} could not be used — {why}")


def _references(db: Any, data_dir: Path, rec_dirs: dict[str, Path], method: str
                ) -> tuple[dict[str, list[dict[str, Any]]], list[str]]:
    """rec_id → reference steps on the recording's time axis, and notes on failures."""
    return _reference_steps(_reference_paths(db, data_dir, rec_dirs), method)


async def _save_upload(file: UploadFile, dest_dir: Path) -> Path:
    """Copy an upload to ``dest_dir/upload<ext>``: refused as the Subjects page refuses a
    reference (app.api.routes._reference: its extensions, size limit, an empty file, in
    the same words)."""
    name = upload_name(file.filename)
    dest = dest_dir / f"upload.{reference_type(name)}"
    with open(dest, "wb") as f:
        await receive(file, f, name)
    return dest


def _subject_info(subject: Any, dates: list[Any] | None = None) -> dict[str, Any]:
    """Header facts of a subject; ``dates`` (of the sessions reported) give the age.

    Normative bands depend on age (one source studied adults over 70), so the age at the
    sessions is shown, not only the birth year. Only the year of birth is stored: the
    age is given as approximate.
    """
    info: dict[str, Any] = {}
    if getattr(subject, "height_m", None):
        info["Height"] = f"{subject.height_m * 100:.0f} cm"
    if getattr(subject, "leg_length_m", None):
        info["Leg length"] = f"{subject.leg_length_m * 100:.0f} cm"
    if getattr(subject, "sex", "unknown") not in (None, "", "unknown"):
        info["Sex"] = subject.sex
    if getattr(subject, "birth_year", None):
        info["Born"] = str(subject.birth_year)
        ages = sorted({d.year - subject.birth_year for d in dates or [] if d is not None})
        if ages:
            info["Age"] = (f"≈ {ages[0]} y" if len(ages) == 1
                           else f"≈ {ages[0]}–{ages[-1]} y") + " at the session" + (
                               "s" if len(dates or []) > 1 else "")
    return info


def _side_groups(sensors: dict[str, list[float]]) -> dict[str, str]:
    """Which side of the walkway each sensor stands on: ``"left"``, ``"right"`` or ``""``
    (on the axis), as seen by a person walking the walkway towards the world's +X.

    The walkway axis is the principal direction of the sensor positions on the floor
    (sensors line the walkway), pointed along +X (the world frame's walkway direction, the
    way the 3D view looks: ``engine.sim.rig`` has S1, S3, S5 on the left); a sensor's side
    is the sign of its offset across it. "Side A / Side B" did not say which side was which.
    """
    ids = list(sensors)
    if len(ids) < 2:
        return dict.fromkeys(ids, "")
    P = np.array([sensors[i][:2] for i in ids], dtype=float)
    c = P.mean(axis=0)
    _, _, vt = np.linalg.svd(P - c)
    d = vt[0]
    # along +X (a walkway along Y: along +Y)
    if d[0] < -1e-6 or (abs(d[0]) <= 1e-6 and d[1] < 0):
        d = -d
    across = (P - c) @ np.array([-d[1], d[0]])  # > 0: left of the walking direction
    tol = 0.1 * max(1e-9, float(np.ptp(across)))
    return {i: ("" if abs(a) <= tol else "left" if a > 0 else "right")
            for i, a in zip(ids, across, strict=True)}


def _sides_of(settings: Any, hub: Any, rec_id: str) -> dict[str, str]:
    """The side of the walkway (:func:`_side_groups`) of each posed sensor of a recording."""
    d = _rec_dir(settings, rec_id, hub)
    poses = an.sensor_poses(d, _live_poses(hub))
    return _side_groups({k: list(np.asarray(v["T_world_sensor"], dtype=float)[:3, 3])
                         for k, v in poses.items() if k in an.part_dirs(d)})


def _subset_words(sensors: tuple[str, ...] | None, sides: dict[str, str]) -> str:
    """A sensor subset as a clinician reads it: "sensors on the left of the walkway (S1, S3,
    S5)" when it is exactly one side's sensors, else "sensors S1, S3"."""
    if sensors is not None:
        for side in ("left", "right"):
            if set(sensors) == {k for k, v in sides.items() if v == side}:
                return f"sensors on the {side} of the walkway ({an.subset_label(sensors)})"
    return _subset(sensors)


#: Query parameters that would put a subject's identity into a URL (access logs,
#: browser history, proxies): refused, the form or body carries them.
_IDENTIFIER_PARAMS = ("subject", "subject_code", "code", "name")


def _no_identifier_in_url(request: Request) -> None:
    given = [k for k in _IDENTIFIER_PARAMS if k in request.query_params]
    if given:
        raise HTTPException(status.HTTP_400_BAD_REQUEST,
                            f"send {given[0]!r} as a form field, not in the URL: a URL is kept "
                            "in access logs and browser history")


def _subset(sensors: tuple[str, ...] | None) -> str:
    return "all sensors" if sensors is None else f"sensors {an.subset_label(sensors)}"


def _audit_recording(db: Any, request: Request, user: Any, rec_id: str, what: str,
                     link: dict[str, Any] | None = None) -> None:
    """Record that ``user`` was given ``what`` (a report, an analysis) of a recording.

    The entry names the subject and session by their numeric ids, never the subject
    code (the trail outlives a deleted subject and must not keep its pseudonym).
    """
    link = _recording_links(db, rec_id).get(rec_id, {}) if link is None else link
    whose = (f"subject {link['subject_id']}, session {link['session_id']}"
             if link.get("subject_id") is not None else "filed under no subject")
    audit_now(db, request, user, "export", f"recording {rec_id}", f"{whose}; {what}")


# ---------------------------------------------------------------------------- routes


#: Recordings per page of ``GET /api/reports/recordings``: by default, and at most.
REPORT_RECORDINGS_PAGE, REPORT_RECORDINGS_PAGE_MAX = 100, 500


@router.get("/recordings")
def list_recordings(response: Response, user: CurrentUser, settings: SettingsDep,
                    hub: HubDep, db: DbDep, q: SearchQ = None,
                    subject_id: Annotated[int | None, Query(ge=1, le=2**63 - 1)] = None,
                    limit: LimitQ = None, offset: OffsetQ = 0) -> list[dict[str, Any]]:
    """Recordings with sensor data on the server, newest first, with their subject, a
    page at a time (``limit`` ≤ 500, default 100; ``offset``; ``X-Total-Count``
    header); ``q`` searches the recording id, its trial label (``label``) and the session
    label, ``subject_id`` keeps one
    subject's (a subject is found by its code with ``POST /api/subjects/search``: a code
    in a URL would be kept in access logs).

    Which recordings have a folder on the server comes from one listing of the
    recordings folder, their order and subjects from the database (two queries); only
    the page's folders are read (their parts and reference). A folder whose parts are
    not there yet (the first part still arriving) is left out of its page.
    """
    page = page_of(limit, offset, REPORT_RECORDINGS_PAGE, REPORT_RECORDINGS_PAGE_MAX)
    root = Path(settings.data_dir) / an.RECORDINGS_DIR
    try:
        with os.scandir(root) as it:
            on_server = {e.name for e in it if e.is_dir()}
    except OSError:  # no recording reached the server yet
        on_server = set()
    needle = q.strip() if q and q.strip() else None
    filed = (select(DbRecording.id, DbRecording.created_at)
             .join(DbSession, DbRecording.session_id == DbSession.id)
             .join(Subject, DbSession.subject_id == Subject.id))
    if needle is not None:
        pat = like_pattern(needle)
        filed = filed.where(DbSession.label.ilike(pat, escape="\\")
                            | DbRecording.label.ilike(pat, escape="\\")
                            | DbRecording.id.ilike(pat, escape="\\"))
    if subject_id is not None:
        filed = filed.where(Subject.id == subject_id)
    live = hub.recordings.recordings
    # (the connection: no ORM row processing of the narrow rows, every filed recording)
    filed_rows = db.connection().execute(filed).all()
    rows: list[tuple[float, str]] = [
        (live[r].created if r in live else _epoch_s(c), r)
        for r, c in filed_rows if r in on_server]
    if subject_id is None:  # recordings filed under no session (e.g. from the Rig page)
        # unfiltered, the rows above are every filed recording already
        known = ({r for r, _ in filed_rows} if needle is None
                 else set(db.connection().execute(select(DbRecording.id)).scalars()))
        for name in on_server - known:
            if needle is not None and needle.lower() not in name.lower():
                continue
            rec = live.get(name)
            try:
                rows.append((rec.created if rec is not None else (root / name).stat().st_mtime,
                             name))
            except OSError:
                continue
    rows.sort(reverse=True)
    set_total(response, len(rows))
    chosen = rows[page.offset:page.offset + page.limit]
    links = _recording_links(db, [r for _, r in chosen])
    out: list[dict[str, Any]] = []
    for created, rec_id in chosen:
        d = root / rec_id
        parts = an.part_dirs(d)
        if not parts:
            continue
        out.append({"id": rec_id, "created": created, "sensors": list(parts),
                    "has_reference": _reference_file(d) is not None,
                    **links.get(rec_id, {})})
    return out


def _epoch_s(t: _dt.datetime) -> float:
    """Seconds since the epoch of a stored time (SQLite gives it back without its UTC
    zone)."""
    return (t if t.tzinfo is not None else t.replace(tzinfo=_dt.UTC)).timestamp()


def _recording_links(db: Any, rec_ids: str | list[str]) -> dict[str, dict[str, Any]]:
    """rec_id → subject/session of the data-management tables, of ``rec_ids`` (one id
    or a list)."""
    want = [rec_ids] if isinstance(rec_ids, str) else rec_ids
    if not want:
        return {}
    rows = (db.query(DbRecording.id, DbRecording.state, DbSession.id, DbSession.label,
                     DbSession.date, Subject.id, Subject.code, DbRecording.label)
            .join(DbSession, DbRecording.session_id == DbSession.id)
            .join(Subject, DbSession.subject_id == Subject.id)
            .filter(DbRecording.id.in_(want)).all())
    return {r[0]: {"db_state": r[1], "session_id": r[2], "session_label": r[3],
                   "session_date": str(r[4]) if r[4] else "", "subject_id": r[5],
                   "subject_code": r[6], "label": r[7] or ""} for r in rows}


@router.get("/recordings/{rec_id}/sensors")
def recording_sensors(rec_id: str, user: CurrentUser, settings: SettingsDep,
                      hub: HubDep) -> dict[str, Any]:
    """The recording's sensors, positions and walkway sides (for subset presets)."""
    d = _rec_dir(settings, rec_id, hub)
    poses = an.sensor_poses(d, _live_poses(hub))
    pos = {k: list(np.asarray(v["T_world_sensor"], dtype=float)[:3, 3])
           for k, v in poses.items() if k in an.part_dirs(d)}
    sides = _side_groups(pos)
    sensors = [{"id": k, "position": [round(float(x), 3) for x in pos[k]] if k in pos else None,
                "side": sides.get(k, ""), "has_pose": k in pos} for k in an.part_dirs(d)]
    return {"rec_id": rec_id, "sensors": sensors}


@router.get("/recordings/{rec_id}/analysis")
def recording_analysis(rec_id: str, request: Request, user: CurrentUser,
                       settings: SettingsDep, hub: HubDep, db: DbDep,
                       sensors: str | None = Query(None, max_length=2000,
                                                   description="e.g. S1,S3,S5; empty = all"),
                       method: MethodQ = "crossing",
                       estimator: EstimatorQ = "weighted") -> dict[str, Any]:
    """Gait analysis of one recording (cached beside the recording); audited."""
    sub = _sensors_param(sensors)
    res = _analyse(settings, hub, rec_id, sub, method, estimator)
    _audit_recording(db, request, user, rec_id,
                     f"analysis json ({method}, {_subset(sub)})")
    return res


def _brief(a: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in a.items() if k not in ("ankles", "placements")}


@router.get("/recordings/{rec_id}/compare")
def compare_subsets(rec_id: str, request: Request, user: CurrentUser, settings: SettingsDep,
                    hub: HubDep, db: DbDep,
                    a: str = Query(..., max_length=2000, description="first subset, e.g. S1,S3,S5"),
                    b: str | None = Query(None, max_length=2000,
                                          description="second subset; empty = all sensors"),
                    method: MethodQ = "crossing",
                    estimator: EstimatorQ = "weighted") -> dict[str, Any]:
    """The same recording analysed with two sensor subsets (one- vs two-sided); audited."""
    sa, sb = _sensors_param(a), _sensors_param(b)
    ra = _analyse(settings, hub, rec_id, sa, method, estimator)
    rb = _analyse(settings, hub, rec_id, sb, method, estimator)
    _audit_recording(db, request, user, rec_id,
                     f"analysis comparison json ({method}, {_subset(sa)} vs {_subset(sb)})")
    return {"rec_id": rec_id, "a": _brief(ra), "b": _brief(rb)}


@router.get("/recordings/{rec_id}/report", response_model=None)
def recording_report(rec_id: str, request: Request, user: CurrentUser, settings: SettingsDep,
                     hub: HubDep, db: DbDep, format: Fmt = "html",
                     sensors: str | None = Query(None, max_length=2000),
                     method: MethodQ = "crossing",
                     estimator: EstimatorQ = "weighted") -> Response:
    """Report of one recording (optionally from a sensor subset); audited."""
    sub = _sensors_param(sensors)
    res = _analyse(settings, hub, rec_id, sub, method, estimator)
    link = _recording_links(db, rec_id).get(rec_id, {})
    code = str(link.get("subject_code") or "unassigned")
    title = "Gait report" + ("" if sub is None
                             else f" — {_subset_words(sub, _sides_of(settings, hub, rec_id))}")
    refs, ref_notes = _references(db, settings.data_dir, {rec_id: _rec_dir(settings, rec_id, hub)},
                                  method)
    try:
        data = an.build_report(code, [res], title=title,
                               session_label=str(link.get("session_label") or ""),
                               session_date=str(link.get("session_date") or ""),
                               references=refs,
                               trial_labels={rec_id: str(link.get("label") or "")})
    except InsufficientDataError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from exc
    except InputError as exc:
        raise HTTPException(status.HTTP_400_BAD_REQUEST, str(exc)) from exc
    except GaitrigError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from exc
    data.quality.notes += ref_notes
    out = _respond(data, format, f"gait-report-{code}-{rec_id}")
    _audit_recording(db, request, user, rec_id,
                     f"report {format} ({method}, {_subset(sub)})", link)
    return out


@dataclass
class SubjectReportSource:
    """What a subject's report needs from the database, read at once, so that the report
    can be built after the database session closed (inside a streamed export)."""

    subject_id: int
    code: str
    where: str  # "subject P07" or "session <label>", for messages
    info: dict[str, Any]  # header facts (:func:`_subject_info`)
    session_label: str
    session_date: str
    file_stamp: str  # date in the PDF's file name
    recordings: list[tuple[str, str]]  # (rec_id, state) in session order
    labels: dict[str, str] = field(default_factory=dict)  # rec_id → trial label
    references: dict[str, ReferenceFile] = field(default_factory=dict)
    #: (session id, label, ISO date, its rec_ids) in time order, when the report spans
    #: several sessions (for "Change over sessions"); empty for one session
    sessions: list[tuple[int, str, str, list[str]]] = field(default_factory=list)


class NothingToReportError(InsufficientDataError):
    """The subject (or session) has no recording complete on the server."""


def subject_report_source(db: Any, data_dir: Path, subject: Any,
                          session: Any | None = None,
                          sessions: list[Any] | None = None) -> SubjectReportSource:
    """Read what the report of ``subject`` (of all its sessions, of ``sessions``, or of
    ``session``) needs from the database."""
    if session is not None:
        chosen = [session]
    else:
        # time order: the first session is the baseline of "Change over sessions"
        chosen = sorted(sessions if sessions is not None else list(subject.sessions),
                        key=lambda s: (s.date is None, s.date or _dt.date.min, s.id))
    recs = [(r.id, r.state) for se in chosen for r in se.recordings]
    subset = session is None and sessions is not None
    return SubjectReportSource(
        subject_id=subject.id, code=subject.code,
        where=(f"session {session.label or session.date}" if session is not None
               else f"subject {subject.code}"),
        info=_subject_info(subject, [s.date for s in chosen]),
        session_label=(session.label if session is not None
                       else f"{'sessions' if subset else 'all sessions'} ({len(chosen)})"),
        session_date=(str(session.date) if session is not None else ", ".join(
            sorted({str(s.date) for s in chosen if s.date}))),
        file_stamp=(str(session.date) if session is not None
                    else _dt.date.today().isoformat()),
        recordings=recs,
        labels={r.id: r.label or "" for se in chosen for r in se.recordings},
        references=_reference_paths(db, data_dir, {
            rec_id: an.recording_dir(data_dir, rec_id) for rec_id, _ in recs}),
        sessions=([] if session is not None else
                  [(s.id, s.label or "", str(s.date) if s.date else "",
                    [r.id for r in s.recordings]) for s in chosen]))


def build_subject_report(src: SubjectReportSource, data_dir: Path, live: dict[str, Any],
                         sensors: tuple[str, ...] | None = None, method: str = "crossing",
                         estimator: str = "weighted") -> ReportData:
    """Analyse a subject's complete recordings and build its report (no database).

    Raises:
        NothingToReportError: no recording of ``src`` is complete on the server.
        GaitrigError: the recordings give no report (e.g. no steps in any).
    """
    analyses: list[dict[str, Any]] = []
    skipped: list[str] = []
    used: set[str] = set()
    for rec_id, state in src.recordings:
        d = an.recording_dir(data_dir, rec_id)
        if state != "complete" or not an.part_dirs(d):
            skipped.append(f"{rec_id} ({an.STATE_WORDS.get(state, state)})")
            continue
        used.add(rec_id)
        try:
            analyses.append(an.analyse_recording(
                d, an.AnalysisOptions(method, estimator, sensors), live))
        except GaitrigError as exc:
            analyses.append({"rec_id": rec_id, "ok": False, "error": str(exc)})
    if not analyses:
        more = f" (not complete on the server: {', '.join(skipped)})" if skipped else ""
        raise NothingToReportError(f"{src.where} has no complete recording to report on{more}; "
                              "record a walk and transfer it to the server first")
    refs, ref_notes = _reference_steps(
        {k: v for k, v in src.references.items() if k in used}, method, src.labels)
    data = an.build_report(
        src.code, analyses,
        title="Gait report" + ("" if sensors is None else f" — {_subset(sensors)}"),
        subject_info=src.info, session_label=src.session_label,
        session_date=src.session_date, references=refs, trial_labels=src.labels)
    data.quality.notes += ref_notes
    data.sessions = _session_trials(src, analyses, data)
    for rec_id, state in src.recordings:
        if rec_id in used:
            continue
        data.quality.notes.append(f"{an.recording_named(rec_id, src.labels.get(rec_id, ''), state)}"
                                  " was not used: it is not complete on the server.")
    return data


def _session_trials(src: SubjectReportSource, analyses: list[dict[str, Any]],
                    data: ReportData) -> list[SessionTrials]:
    """The report's trials grouped by session (sessions without a usable trial left out).

    ``build_report`` makes one trial per successful analysis, in their order.
    """
    good = [a for a in analyses if a.get("ok")]
    by_rec = {str(a.get("rec_id")): t for a, t in zip(good, data.trials, strict=True)}
    out = []
    for sid, label, date, rec_ids in src.sessions:
        trials = [by_rec[r] for r in rec_ids if r in by_rec]
        if trials:
            out.append(SessionTrials(label, date, trials, sid))
    return out


def _sessions_param(value: str | None) -> list[int] | None:
    """``"3,5"`` → ``[3, 5]``; None when not given."""
    if value is None:
        return None
    parts = [p.strip() for p in value.split(",") if p.strip()]
    if not parts:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            "sessions: give at least one session id (e.g. sessions=3,5), or "
                            "leave it out for all sessions")
    try:
        ids = [int(p) for p in parts]
    except ValueError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"sessions: {value[:100]!r} must be session ids separated by "
                            "commas, e.g. sessions=3,5") from exc
    return list(dict.fromkeys(ids))


@router.get("/subjects/{subject_id}", response_model=None)
def subject_report(subject_id: int, request: Request, user: CurrentUser,
                   settings: SettingsDep, hub: HubDep, db: DbDep, format: Fmt = "html",
                   session_id: int | None = None,
                   sessions: str | None = Query(None, max_length=2000, description=(
                       "ids of some of the subject's sessions, comma-separated; two or "
                       "more add the section 'Change over sessions'")),
                   sensors: str | None = Query(None, max_length=2000),
                   method: MethodQ = "crossing",
                   estimator: EstimatorQ = "weighted") -> Response:
    """Report of a subject from all complete recordings, those of some sessions
    (``sessions``) or of one session (``session_id``); audited.

    A report over two or more sessions has the section "Change over sessions".
    """
    subject = get_row(db, Subject, subject_id)
    if subject is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no subject with id {subject_id}")
    sess = None
    picked: list[Any] | None = None
    wanted = _sessions_param(sessions)
    if wanted is not None and session_id is not None:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            "give either session_id (one session) or sessions (several), "
                            "not both")
    if wanted is not None:
        own = {s.id: s for s in subject.sessions}
        missing = [i for i in wanted if i not in own]
        if missing:
            raise HTTPException(status.HTTP_404_NOT_FOUND,
                                f"subject {subject.code} has no session with id "
                                f"{', '.join(map(str, missing))}")
        picked = [own[i] for i in wanted]
    if session_id is not None:
        sess = next((s for s in subject.sessions if s.id == session_id), None)
        if sess is None:
            raise HTTPException(status.HTTP_404_NOT_FOUND,
                                f"subject {subject.code} has no session with id {session_id}")
    sub = _sensors_param(sensors)
    src = subject_report_source(db, settings.data_dir, subject, sess, picked)
    try:
        data = build_subject_report(src, settings.data_dir, _live_poses(hub), sub, method,
                                    estimator)
    except NothingToReportError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from exc
    except InsufficientDataError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"{src.where}: {exc}") from exc
    except InputError as exc:
        raise HTTPException(status.HTTP_400_BAD_REQUEST, str(exc)) from exc
    except GaitrigError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"{src.where}: {exc}") from exc
    out = _respond(data, format, f"gait-report-{subject.code}-{src.file_stamp}")
    audit_now(db, request, user, "export", f"subject {subject_id}",
              (f"session {session_id}" if sess is not None
               else f"sessions {', '.join(str(s.id) for s in picked)}" if picked is not None
               else f"all sessions ({len(subject.sessions)})")
              + f"; report {format} ({method}, {_subset(sub)})")
    return out


# ---------------------------------------------------------------------------- project study


#: The console's words for the analysis options (the Reports page's lists).
METHOD_WORDS = {"crossing": "Foot placements", "heelstrike": "Heel strike / toe off"}
ESTIMATOR_WORDS = {"weighted": "Weighted by view angle", "mean": "Equal-weight mean"}
#: Steps of the system and of the reference further apart in time are not paired (s).
STUDY_MAX_DT_S = 0.25


@dataclass
class ProjectStudySource:
    """What a project's agreement study needs from the database, read at once."""

    project_id: int
    name: str
    #: (subject code, rec_id, trial label) of each complete recording with a reference,
    #: subjects by code, sessions by date
    trials: list[tuple[str, str, str]]
    references: dict[str, ReferenceFile]
    n_without: int  # complete recordings without a reference (not in the study)
    #: recordings with a reference that are not complete on the server (named in notes)
    not_complete: list[str] = field(default_factory=list)


class NoReferenceError(InsufficientDataError):
    """The project has no complete recording with a reference attached."""


def project_study_source(db: Any, data_dir: Path, project: Any) -> ProjectStudySource:
    """Read which recordings of ``project`` take part in its agreement study."""
    recs: list[tuple[str, str, str, str]] = []  # (code, rec_id, label, state)
    for subj in sorted(project.subjects, key=lambda x: (x.code, x.id)):
        for se in sorted(subj.sessions,
                         key=lambda s: (s.date is None, s.date or _dt.date.min, s.id)):
            recs += [(subj.code, r.id, r.label or "", r.state) for r in se.recordings]
    refs = _reference_paths(db, data_dir, {
        rec_id: an.recording_dir(data_dir, rec_id) for _, rec_id, _, _ in recs})
    trials: list[tuple[str, str, str]] = []
    not_complete: list[str] = []
    n_without = 0
    for code, rec_id, label, state in recs:
        complete = state == "complete" and bool(an.part_dirs(an.recording_dir(data_dir, rec_id)))
        if rec_id not in refs:
            n_without += int(complete)
        elif complete:
            trials.append((code, rec_id, label))
        else:
            not_complete.append(an.recording_named(rec_id, label, state))
    return ProjectStudySource(project.id, project.name, trials, refs, n_without, not_complete)


def build_project_study(src: ProjectStudySource, data_dir: Path, live: dict[str, Any],
                        sensors: tuple[str, ...] | None = None, method: str = "crossing",
                        estimator: str = "weighted") -> StudyReport:
    """Analyse each recording of a project with a reference, and its reference, and fit
    the agreement study (seed 000's Tables 1–3) over the project's subjects (no database).

    A recording whose analysis or reference gives no steps is a note; the others go on.

    Raises:
        NoReferenceError: no complete recording of the project has a reference.
        InsufficientDataError: too few steps match the reference for any row.
    """
    from engine.agreement import AgreementStudy, StudyTrial
    from engine.report.study import StudyReport

    if not src.trials:
        more = (f" (not complete on the server: {', '.join(src.not_complete)})"
                if src.not_complete else "")
        raise NoReferenceError(
            f"project {src.name} has no recording with a reference attached{more}; attach "
            "one to each validation walk (Reports page, 'Reference recording for the "
            "agreement section', or the Subjects page)")
    notes = [f"{t} was not used: it is not complete on the server." for t in src.not_complete]
    by_subject: dict[str, list[StudyTrial]] = {}
    for code, rec_id, label in src.trials:
        trial = an.recording_named(rec_id, label)
        try:
            a = an.analyse_recording(an.recording_dir(data_dir, rec_id),
                                     an.AnalysisOptions(method, estimator, sensors), live)
        except GaitrigError as exc:  # e.g. a sensor of the subset this recording lacks
            notes.append(f"{trial} was not used: {exc}")
            continue
        if not a.get("ok"):
            notes.append(f"{trial} was not used: {a.get('error')}")
            continue
        path, off, name = src.references[rec_id]
        try:
            ref = an.reference_gait(path, method)
        except GaitrigError as exc:
            notes.append(_reference_refused(trial, exc, path, name))
            continue
        except (ArithmeticError, ValueError, IndexError, np.linalg.LinAlgError) as exc:
            # an engine defect on an unusual file: a note, the other trials go on
            notes.append(f"{trial}: the reference {name} could not be analysed "
                         f"({type(exc).__name__}: {exc})")
            continue
        by_subject.setdefault(code, []).append(an.study_trial(a["gait"], ref, off, trial))
    try:
        study = AgreementStudy(max_dt_s=STUDY_MAX_DT_S).fit(by_subject)
    except InsufficientDataError as exc:
        raise InsufficientDataError(
            f"project {src.name}: {exc}" + (f" ({'; '.join(notes)})" if notes else "")
        ) from exc
    n_with = len(src.trials)
    basis = [f"Project {src.name}: {count(study.n_subjects_, 'subject')}, "
             f"{count(study.n_trials_, 'trial')} with a reference"
             + (f" ({n_with - study.n_trials_} more left out, see the notes)"
                if n_with > study.n_trials_ else "")
             + (f"; {count(src.n_without, 'complete recording')} without a reference "
                "not part of the study" if src.n_without else "") + ".",
             f"Sensors: {an.subset_label(sensors)}.",
             f"Sensor fusion: {ESTIMATOR_WORDS.get(estimator, estimator)}.",
             f"Gait events: {METHOD_WORDS.get(method, method)}, on both systems; steps "
             f"paired with the reference's steps of the same side within "
             f"{STUDY_MAX_DT_S:g} s."]
    return StudyReport(study, basis=basis, notes=notes)


def _json_safe(v: Any) -> Any:
    """NaN and infinities as None (JSON has neither)."""
    return None if isinstance(v, float) and not np.isfinite(v) else v


@router.get("/projects/{project_id}/agreement", response_model=None)
def project_agreement(project_id: int, request: Request, user: CurrentUser,
                      settings: SettingsDep, hub: HubDep, db: DbDep,
                      format: Literal["html", "pdf", "csv", "json"] = "html",
                      sensors: str | None = Query(None, max_length=2000, description=(
                          "e.g. S1,S3,S5 (a one-sided study); empty = all sensors")),
                      method: MethodQ = "crossing",
                      estimator: EstimatorQ = "weighted",
                      reference_name: str = Query("", max_length=40, description=(
                          "the reference system's name heading its columns, e.g. Vicon "
                          "(empty: 'reference')"))) -> Response:
    """Agreement with a reference system over a project (seed 000's Tables 1–3 at its
    three levels): every complete recording of the project's subjects with a reference
    attached, analysed with the options given and paired with its reference; audited."""
    project = get_row(db, Project, project_id)
    if project is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no project with id {project_id}")
    sub = _sensors_param(sensors)
    src = project_study_source(db, settings.data_dir, project)
    try:
        report = build_project_study(src, settings.data_dir, _live_poses(hub), sub, method,
                                     estimator)
    except InputError as exc:
        raise HTTPException(status.HTTP_400_BAD_REQUEST, str(exc)) from exc
    except GaitrigError as exc:  # no reference, too few matched steps
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from exc
    from engine.report.study import render_study_html, render_study_pdf

    report.reference = " ".join(reference_name.split()) or report.reference
    study = report.study
    stem = _filename("agreement", src.name, _dt.date.today().isoformat())
    out: Response
    try:
        if format == "json":
            out = Response(json.dumps({
                "project": src.name, "subjects": study.n_subjects_, "trials": study.n_trials_,
                "rows": [{k: _json_safe(v) for k, v in r.to_dict().items()}
                         for r in study.rows_],
                "unmatched": study.unmatched_, "notes": report.notes,
                "basis": report.basis}), media_type="application/json")
        elif format == "csv":
            out = Response(study.csv(), media_type="text/csv", headers={
                "Content-Disposition": f'attachment; filename="{stem}.csv"'})
        elif format == "pdf":
            out = Response(render_study_pdf(report), media_type="application/pdf", headers={
                "Content-Disposition": f'attachment; filename="{stem}.pdf"'})
        else:
            out = HTMLResponse(render_study_html(report, standalone=False))
    except GaitrigError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from exc
    audit_now(db, request, user, "export", f"project {project_id}",
              f"agreement {format} ({method}, {estimator}, {_subset(sub)}; "
              f"{count(study.n_subjects_, 'subject')}, {count(study.n_trials_, 'trial')})")
    return out


@router.get("/recordings/{rec_id}/reference")
def get_reference(rec_id: str, user: CurrentUser, settings: SettingsDep,
                  hub: HubDep) -> dict[str, Any]:
    """The reference attached to a recording (``attached`` False when none)."""
    ref = _reference_file(_rec_dir(settings, rec_id, hub))
    if ref is None:
        return {"rec_id": rec_id, "attached": False}
    return {"rec_id": rec_id, "attached": True, **ref[1]}


@router.post("/recordings/{rec_id}/reference", status_code=201,
             max_body_size=_UPLOAD_BODY_MAX)
@refused_with(_reference.too_large)  # a request too large: receive()'s words, unnamed
async def put_reference(rec_id: str, file: UploadFile, user: CurrentUser,
                        settings: SettingsDep, hub: HubDep,
                        offset_s: float = Query(0.0, ge=-3600, le=3600,
                                                description="seconds into the recording at "
                                                "which the reference starts (added to its "
                                                "times; negative: it started before)")
                        ) -> dict[str, Any]:
    """Attach a reference recording (C3D/TRC/CSV); it must contain a walk with steps."""
    d = _rec_dir(settings, rec_id, hub)
    _sweep_stale_uploads(d)
    # The new folder (file and meta.json) is made in a temporary folder whose name ends in
    # .tmp (backups leave it out; removed on any failure, or by a later upload after a
    # kill) and swapped in by renames: a backup never takes a half-written reference.
    with tempfile.TemporaryDirectory(dir=d, prefix=_UPLOAD_PREFIX, suffix=".tmp") as tmp:
        path = await _save_upload(file, Path(tmp))
        # as on the Subjects page (app.api.routes._reference): 400 for a file no reader
        # takes, 422 for one with no usable walk in it, in the same words; the reference
        # attached here before stays, and is named
        before = _reference_file(d)
        _, steps = await asyncio.to_thread(
            check_reference, path, path.suffix.lstrip("."), upload_name(file.filename),
            [str(before[1].get("filename") or "") or before[0].name] if before else [])
        # its upload time tells it from a later upload when a restore re-applies the
        # deletion of this one (app.server.erasures)
        meta = {"filename": (file.filename or "")[-200:], "ext": path.suffix,
                "offset_s": offset_s, "n_steps": len(steps),
                "uploaded": erasures.stamp(_dt.datetime.now(_dt.UTC))}
        new = Path(tmp) / "reference"
        new.mkdir()
        os.replace(path, new / f"reference{path.suffix}")
        (new / "meta.json").write_text(json.dumps(meta))
        folder = d / "reference"
        if folder.exists():
            os.replace(folder, Path(tmp) / "replaced")  # deleted with the temporary folder
        os.replace(new, folder)
    note_changed(folder)  # the recording's bytes on the server (GET /api/storage)
    return {"rec_id": rec_id, "attached": True, **meta}


def _file_error(exc: BaseException, copy: Path, name: str, text: str | None = None) -> str:
    """Why "Analyse a file" gave no report of ``name`` (read from ``copy``), naming the
    file once, as a refused reference does: "'trial 3.c3d' is not a readable C3D file:
    the file is damaged…", "walk.trc: no steps were found" (was "trial 3.c3d: cannot read
    trial 3.c3d as C3D: …", "Gang.trc: Gang.trc is not a TRC file …"). ``text`` is said
    instead of the error's message when given (:func:`form_say`'s words)."""
    why = refusal(exc, copy, name, text)
    return why if name in why else f"{name}: {why}"


#: The Reports page's disclosure with the options of "Analyse a file".
FILE_OPTIONS = "Options for files from other labs"


def _axis_words(up: str) -> str:
    """``"-z"`` → ``"Z down"``, ``"y"`` → ``"Y up"`` (the page's vertical-axis choices)."""
    return f"{up[-1].upper()} {'down' if up.startswith('-') else 'up'}"


#: The Reports page's choices of "ankle markers" (``static/reports.html``).
_ANKLE_LABELS = {"auto": "Automatic", "lateral": "On the lateral malleoli",
                 "joint": "At the ankle joint centres"}


def form_say(option: str, value: str | None, verb: str, example: str | None) -> str:
    """An option named in an engine error's reason or advice
    (:meth:`engine.errors.GaitrigError.words`), as the Reports page's field under
    "Options for files from other labs": ``{up=z}`` "the vertical axis Z up",
    ``{up:give}`` with example ``x`` "choose the vertical axis under '…', e.g. X up",
    ``{markers:by}`` "by giving the left and right foot markers under '…'",
    ``{ankle_markers:clear}`` "set the ankle markers to Automatic", ``{ankle_width_mm=70}``
    "70"."""
    under = f"under '{FILE_OPTIONS}'"
    the = OPTION_NAMES[option]
    auto = "leave it empty" if option in ("ankle_width_mm", "markers") else "Automatic"
    eg = ("" if example is None else f", e.g. {_axis_words(example)}" if option == "up"
          else f", e.g. {example} as the left one" if option == "markers"
          else f", e.g. {example}")
    if verb == "":
        if option == "markers":
            return "left and right foot markers"
        if option == "ankle_width_mm":
            return value or the  # a width as typed in the field: "70 or 68,72"
        if value is None:
            return the
        return {"up": f"the vertical axis {_axis_words(value)}",
                "units": f"the units {value}",
                "ankle_markers": f"ankle markers '{_ANKLE_LABELS.get(value, value)}'",
                }[option]
    if verb == "both" and option == "markers":
        return f"give both the left and the right foot marker {under}, or neither"
    if verb == "by":
        return f"by giving {the} {under}{eg}"
    if verb == "change":
        if option == "up" and example is not None:
            return f"choose {_axis_words(example)} as the vertical axis {under}, or {auto}"
        if option == "units":
            return f"choose other units {under}, or {auto}"
        return f"change {the} {under}{eg}, or {auto}"
    if verb == "clear":
        return (f"leave {the} empty" if auto == "leave it empty"
                else f"set {the} to Automatic")
    # "give" (and "both" of a single option)
    act = "give" if option in ("markers", "ankle_width_mm") else "choose"
    return f"{act} {the} {under}{eg}"


#: Name start of a report reference's temporary upload folder (which ends in ``.tmp``).
_UPLOAD_PREFIX = ".reference-upload-"


def _sweep_stale_uploads(rec_dir: Path) -> None:
    """Remove temporary upload folders of a recording older than a day (a killed server's)."""
    now = _dt.datetime.now().timestamp()
    for p in rec_dir.glob(f"{_UPLOAD_PREFIX}*.tmp"):
        try:
            if now - p.stat().st_mtime > 86400.0:
                shutil.rmtree(p, ignore_errors=True)
        except OSError:
            continue


@router.delete("/recordings/{rec_id}/reference")
def delete_reference(rec_id: str, user: CurrentUser, settings: SettingsDep,
                     hub: HubDep) -> dict[str, Any]:
    """Detach the reference recording (logged in the erasure log, docs/backup.md)."""
    d = _rec_dir(settings, rec_id, hub)
    folder = d / erasures.REPORT_REFERENCE_DIR
    if not folder.is_dir():
        return {"rec_id": rec_id, "attached": False}
    eid = erasures.begin(settings.data_dir, [], None, {},
                         [(rec_id, erasures.report_reference_uploaded(folder))])
    # the rename is the deletion (atomic); the removal of the renamed folder may fail
    # without bringing the reference back (a later upload sweeps it)
    gone = d / f"{_UPLOAD_PREFIX}deleted-{secrets.token_hex(4)}.tmp"
    try:
        os.replace(folder, gone)
    except OSError as exc:
        erasures.finish(settings.data_dir, eid, committed=False)
        raise HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE,
                            f"the reference of {rec_id} could not be deleted "
                            f"({exc.strerror or exc}); try again") from exc
    erasures.finish(settings.data_dir, eid, committed=True)
    shutil.rmtree(gone, ignore_errors=True)
    note_changed(folder)  # the recording's bytes on the server (GET /api/storage)
    return {"rec_id": rec_id, "attached": False}


@router.post("/upload", response_model=None,
             max_body_size=_UPLOAD_BODY_MAX)
@refused_with(_reference.too_large)  # a request too large: receive()'s words, unnamed
async def upload_report(request: Request, file: UploadFile, user: CurrentUser, db: DbDep,
                        subject: Annotated[str, Form(min_length=1, max_length=40, description=(
                            "subject code printed on the report (a form field: a URL is "
                            "kept in access logs and browser history)"))] = "upload",
                        format: Fmt = "html",
                        method: MethodQ = "crossing",
                        left: str | None = Query(None, max_length=64),
                        right: str | None = Query(None, max_length=64),
                        up: Literal["x", "y", "z", "-x", "-y", "-z"] | None = None,
                        ankle_markers: Literal["auto", "lateral", "joint"] = "auto",
                        ankle_width_mm: str | None = Query(None, max_length=32, description=(
                            "ankle width(s) in mm, one for both feet or left,right "
                            "(gaitrig gait --ankle-width-mm)")),
                        units: Literal["mm", "cm", "m"] | None = Query(None, description=(
                            "length unit of the file's coordinates, overriding the file's "
                            "own (gaitrig gait --units)")),
                        advice: Literal["cli", "form"] = Query("cli", description=(
                            "how a refusal names the options: 'cli' as gaitrig gait's flags "
                            "(--up), 'form' as the Reports page's fields"))) -> Response:
    """Report of an uploaded C3D/TRC/skeleton-CSV file (kept only while analysed).

    The subject code comes in the multipart form, never in the URL. ``left``, ``right``,
    ``up``, ``units``, ``ankle_markers`` and ``ankle_width_mm`` are ``gaitrig gait``'s
    options; with ``advice=form`` (the Reports page) a refusal names them as the page's
    fields under "Options for files from other labs" instead of as command-line flags.
    """
    import anyio

    _no_identifier_in_url(request)
    widths_m: tuple[float, ...] | None = None
    if ankle_width_mm is not None:
        try:
            widths_m = tuple(float(x) / 1000.0 for x in ankle_width_mm.split(","))
        except ValueError:
            what = ("the ankle width" if advice == "form" else "ankle_width_mm")
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                f"{what} {ankle_width_mm!r} is not a width in mm: give "
                                "one number for both feet or left,right, e.g. 70 or 68,72"
                                ) from None

    with tempfile.TemporaryDirectory(prefix="gaitrig-upload-") as tmp:
        path = await _save_upload(file, Path(tmp))

        def work() -> Response:
            try:
                res = an.analyse_file(path, method, left, right, up, units, ankle_markers,
                                      widths_m)
                res["rec_id"] = Path(file.filename or "upload").name[-80:]
                data = an.build_report(subject, [res], title="Gait report (uploaded file)")
            except GaitrigError as exc:
                # an error raised with its message only names no option: said as it is
                said = exc.words(form_say) if advice == "form" else None
                why = _file_error(exc, path, file.filename or "the file", said)
                raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, why) from exc
            return _respond(data, format, f"gait-report-{subject}")

        out = await anyio.to_thread.run_sync(work)
    # an uploaded file belongs to no subject here: the entry names the file's type only
    await anyio.to_thread.run_sync(audit_now, db, request, user, "export", "uploaded file",
                                   f"report {format} of a {path.suffix} file ({method})")
    return out
