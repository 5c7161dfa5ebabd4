"""The erasure log: every deletion of health data, kept so that a restore re-applies it.

A backup taken before a subject was deleted still holds that subject. Restoring it must
not bring the subject back (the deletion was the data subject's right), so every
deletion is appended to ``<data_dir>/erasures.jsonl`` and ``gaitrig restore`` deletes
again, from the restored database and files, whatever the log says was deleted.

The log holds no pseudonym, no content and not even the deleted recordings' ids (after
a deletion only the audit trail names them): a row is named by its table, numeric id
and creation time (ids can be reused by SQLite after the newest row is deleted; the
creation time, to the microsecond, tells a later row with the same id apart), a
recording by a SHA-256 of its id (:func:`rec_key`; a restore recognises the recordings
of the backup by it) with the nodes that held a part. The hash has no secret key: it
keeps the id out of plain sight (a reader or a text search of the log does not meet it)
but does not hide it from someone who tries candidates — an id is its start second and 4
hex digits, 65 536 guesses per second of a plausible time — and the row's creation time
beside it is about that start anyway. What the id would reveal is only that a recording
started at that second; the subject is named nowhere in the log. A reference recording
deleted on its own is logged too: an imported one (``/api/exports/.../references``) as
its ``reference_imports`` row, a report's (``recordings/<id>/reference/``, no row) in
``references`` as the :func:`rec_key` of its recording and its upload time (``""`` for
one uploaded before uploads were timed). Lines are appended and synced, never
rewritten::

    {"id": "<hex>", "state": "started", "at": "...", "rows": [["subjects", 5, "..."]],
     "recordings": {"<rec_key of R20261122-101500-ab12>": ["S1", "S2"]},
     "references": [["<rec_key>", "2026-11-22T10:20:00.123456+00:00"]]}
    {"id": "<hex>", "state": "done", "at": "..."}        # the deletion committed
    {"id": "<hex>", "state": "void", "at": "..."}        # it failed: nothing was deleted

``started`` is written before the deletion commits (a crash in between must not lose
it); ``done``/``void`` after. An entry left ``started`` by a crash is settled when the
server starts (:func:`settle`): ``void`` if its rows survived, else ``done``. A restore
applies every entry that is not ``void``.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import threading
import uuid
from collections.abc import Iterable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session as DbSession

from app.db import data as m

LOG_NAME = "erasures.jsonl"

#: Tables a deletion can name, with their models.
_MODELS: dict[str, Any] = {"projects": m.Project, "subjects": m.Subject,
                           "sessions": m.Session, "recordings": m.Recording,
                           "reference_imports": m.ReferenceImport}

#: A report reference's folder in a recording's folder, and its description in it.
REPORT_REFERENCE_DIR = "reference"
_REPORT_REFERENCE_META = "meta.json"

_SAFE_NAME = re.compile(r"[A-Za-z0-9_.-]{1,80}")

_LOCK = threading.Lock()  # deletions run in worker threads


def log_path(data_dir: Path) -> Path:
    """The erasure log of a data folder."""
    return Path(data_dir) / LOG_NAME


def rec_key(rec_id: str) -> str:
    """How the log names a recording: a SHA-256 of its id with a fixed prefix.

    A restore computes the key of every recording it holds to recognise the deleted ones.
    Not keyed (no secret): it keeps the id out of plain text, it does not stop someone who
    hashes candidate ids (start second + 4 hex digits) from finding it — which reveals
    only that a recording started at that second.
    """
    return hashlib.sha256(b"gaitrig erasure log\0" + rec_id.encode()).hexdigest()


def stamp(value: datetime | None) -> str:
    """A row's creation time as the log writes it (UTC, microseconds).

    SQLite gives the stored time back without its zone (it is UTC, ``app.db.data._now``);
    PostgreSQL with it: both end up as the same string.
    """
    if value is None:
        return ""
    if value.tzinfo is None:
        value = value.replace(tzinfo=UTC)
    return value.astimezone(UTC).isoformat(timespec="microseconds")


@dataclass
class Erasure:
    """One deletion of the log.

    Attributes:
        id: random id of the entry.
        state: ``started``, ``done`` or ``void``.
        at: when the deletion started (UTC, ISO 8601).
        rows: ``(table, id, created_at)`` of the rows deleted (their children went with
            them: a subject's sessions and recordings); a recording's id is its
            :func:`rec_key`.
        recordings: :func:`rec_key` of each recording deleted → the nodes that held a
            part.
        references: ``(rec_key, uploaded)`` of each report reference deleted on its own.
    """

    id: str
    state: str
    at: str
    rows: list[tuple[str, int | str, str]] = field(default_factory=list)
    recordings: dict[str, list[str]] = field(default_factory=dict)
    references: list[tuple[str, str]] = field(default_factory=list)


def _append(path: Path, record: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    line = (json.dumps(record, separators=(",", ":")) + "\n").encode()
    with _LOCK:
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o600)
        try:
            os.write(fd, line)
            os.fsync(fd)
        finally:
            os.close(fd)


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="microseconds")


def begin(data_dir: Path, recs: Iterable[m.Recording], owner: Any,
          plan: dict[str, list[str]],
          report_references: Iterable[tuple[str, str]] = ()) -> str:
    """Log a deletion before it commits.

    Args:
        data_dir: the server's data folder.
        recs: the recording rows deleted.
        owner: the session, subject, project or reference import deleted with them (or
            None).
        plan: recording id → nodes holding a part (includes unfiled recordings).
        report_references: ``(recording id, uploaded)`` of each report reference folder
            deleted (:func:`report_reference_uploaded`).

    Returns:
        The entry's id, for :func:`finish`.
    """
    rows: list[list[Any]] = []
    if owner is not None:
        table = str(owner.__tablename__)
        rows.append([table, int(owner.id), stamp(owner.created_at)])
    rows += [["recordings", rec_key(r.id), stamp(r.created_at)] for r in recs]
    eid = uuid.uuid4().hex
    record: dict[str, Any] = {"id": eid, "state": "started", "at": _now(), "rows": rows,
                              "recordings": {rec_key(k): sorted(v) for k, v in plan.items()}}
    refs = [[rec_key(r), str(u)] for r, u in report_references]
    if refs:
        record["references"] = refs
    _append(log_path(data_dir), record)
    return eid


def finish(data_dir: Path, eid: str, committed: bool) -> None:
    """Mark a logged deletion as committed (``done``) or failed (``void``)."""
    _append(log_path(data_dir), {"id": eid, "state": "done" if committed else "void",
                                 "at": _now()})


def parse(text: str, source: str = "the erasure log") -> list[Erasure]:
    """The entries of a log's text, in order, each with its final state.

    Raises:
        ValueError: a line is not an entry of an erasure log (names ``source`` and the
            line).
    """
    out: dict[str, Erasure] = {}
    for k, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
            eid, state = str(rec["id"]), str(rec["state"])
            if state == "started":
                out[eid] = Erasure(
                    eid, state, str(rec["at"]),
                    [(str(t), str(i) if t == "recordings" else int(i), str(c))
                     for t, i, c in rec.get("rows", [])],
                    {str(r): [str(n) for n in ns]
                     for r, ns in dict(rec.get("recordings", {})).items()},
                    [(str(k), str(u)) for k, u in rec.get("references", [])])
            elif state in ("done", "void"):
                if eid in out:
                    out[eid].state = state
            else:
                raise ValueError(f"unknown state {state!r}")
        except (ValueError, KeyError, TypeError) as exc:
            if k == len(text.splitlines()) and not text.endswith("\n"):
                continue  # the last line was cut short by a crash while appending
            raise ValueError(f"{source}, line {k}: not an erasure log entry ({exc})") from exc
    return list(out.values())


def read(data_dir: Path) -> list[Erasure]:
    """The entries of a data folder's log ([] when there is none)."""
    path = log_path(data_dir)
    if not path.is_file():
        return []
    return parse(path.read_text(), str(path))


def merge(*logs: Iterable[Erasure]) -> list[Erasure]:
    """The union of several logs (an entry's most final state wins)."""
    rank = {"started": 0, "done": 1, "void": 2}
    out: dict[str, Erasure] = {}
    for log in logs:
        for e in log:
            have = out.get(e.id)
            if have is None or rank[e.state] > rank[have.state]:
                out[e.id] = e
    return sorted(out.values(), key=lambda e: e.at)


def _rec_ids(db: DbSession) -> dict[str, str]:
    """:func:`rec_key` → id of every recording row."""
    return {rec_key(i): i for i in db.scalars(select(m.Recording.id))}


def _row(db: DbSession, table: str, row_id: int | str, created: str,
         rec_ids: dict[str, str]) -> Any:
    model = _MODELS.get(table)
    if model is None:
        return None
    if table == "recordings":
        row_id = rec_ids.get(str(row_id), "")
    obj = db.get(model, row_id)
    if obj is None or stamp(obj.created_at) != created:
        return None  # gone, or a later row that reuses the id
    return obj


def settle(db: DbSession, data_dir: Path) -> int:
    """Settle the entries a crash left ``started`` (at start-up): ``void`` when one of
    their rows still exists (the deletion never committed), else ``done``.

    Returns:
        How many entries were settled.
    """
    n = 0
    todo = [e for e in read(data_dir) if e.state == "started"]
    ids = _rec_ids(db) if todo else {}
    refs = report_references(data_dir) if any(e.references for e in todo) else {}
    for e in todo:
        alive = (any(_row(db, t, i, c, ids) is not None for t, i, c in e.rows)
                 or any(refs.get(k) == u for k, u in e.references))
        finish(data_dir, e.id, committed=not alive)
        n += 1
    return n


def apply(db: DbSession, entries: Iterable[Erasure]) -> dict[str, list[str]]:
    """Delete again, from a (restored) database, every row the entries deleted.

    A row is deleted only when its id *and* creation time match (a later row that
    reuses an id is kept). Children go with their row (a subject's sessions, their
    recordings, parts and references). Commits.

    Returns:
        The id of every recording row deleted → the nodes that held a part: their files
        are to go as well (the recordings filed under no session have no row: the
        caller finds them by :func:`erased_keys`).
    """
    ids = _rec_ids(db)
    keys = erased_keys(entries)
    recs: dict[str, set[str]] = {}
    for e in entries:
        if e.state == "void":
            continue
        for table, row_id, created in e.rows:
            obj = _row(db, table, row_id, created, ids)
            if obj is None:
                continue
            for r in _recordings_of(obj):
                recs.setdefault(r.id, set()).update(p.node_id for p in r.parts)
            db.delete(obj)
            db.flush()
    for rec_id in list(recs):
        recs[rec_id].update(keys.get(rec_key(rec_id), []))
    db.commit()
    return {k: sorted(v) for k, v in sorted(recs.items())}


def erased_keys(entries: Iterable[Erasure]) -> dict[str, list[str]]:
    """:func:`rec_key` of every recording the (not void) entries deleted → its nodes."""
    out: dict[str, set[str]] = {}
    for e in entries:
        if e.state == "void":
            continue
        for k, nodes in e.recordings.items():
            out.setdefault(k, set()).update(nodes)
        for t, i, _ in e.rows:
            if t == "recordings":
                out.setdefault(str(i), set())
    return {k: sorted(v) for k, v in out.items()}


def _recordings_of(obj: Any) -> list[m.Recording]:
    if isinstance(obj, m.Recording):
        return [obj]
    if isinstance(obj, m.Session):
        return list(obj.recordings)
    if isinstance(obj, m.Subject):
        return [r for s in obj.sessions for r in s.recordings]
    if isinstance(obj, m.Project):
        return [r for x in obj.subjects for s in x.sessions for r in s.recordings]
    return []


def report_reference_uploaded(folder: Path) -> str:
    """The upload time a report reference folder's meta.json records (``""``: none)."""
    try:
        meta = json.loads((folder / _REPORT_REFERENCE_META).read_text())
    except (OSError, ValueError):
        return ""
    return str(meta.get("uploaded", "")) if isinstance(meta, dict) else ""


def report_references(data_dir: Path) -> dict[str, str]:
    """:func:`rec_key` of every recording of a data folder with a report reference →
    that reference's upload time."""
    out: dict[str, str] = {}
    for folder in sorted((Path(data_dir) / "recordings").glob(f"*/{REPORT_REFERENCE_DIR}")):
        if folder.is_dir() and not folder.is_symlink():
            out[rec_key(folder.parent.name)] = report_reference_uploaded(folder)
    return out


def erased_report_references(entries: Iterable[Erasure]) -> set[tuple[str, str]]:
    """``(rec_key, uploaded)`` of every report reference the (not void) entries deleted."""
    return {(k, u) for e in entries if e.state != "void" for k, u in e.references}


def reference_files(db: DbSession, entries: Iterable[Erasure]) -> list[Path]:
    """The files, relative to the data folder, of the reference imports the (not void)
    entries deleted and ``db`` still holds: call before :func:`apply` deletes the rows."""
    ids = _rec_ids(db)
    out = []
    for e in entries:
        if e.state == "void":
            continue
        for table, row_id, created in e.rows:
            if table != "reference_imports":
                continue
            ref = _row(db, table, row_id, created, ids)
            names = (ref.recording_id, ref.stored_name) if ref is not None else ()
            # names from a restored database: never a path out of the references folder
            if names and all(_SAFE_NAME.fullmatch(n) and n not in (".", "..") for n in names):
                out.append(Path("references", *names))
    return out
