"""The list endpoints a clinician's pages ask on every visit (the storage overview, the
subjects page with counts and bytes, the recordings page, a subject's sessions) answer
what the slow, obvious computation does — rows read straight from the SQLite file,
bytes summed from the files on disk — on a medium data folder, and go on doing so after
a recording is added, transferred, deleted, or a file of it vanishes (found by the
periodic check). ``GET /api/storage`` keeps its answer between requests
(:func:`app.api.routes.storage._subjects_json`), so each of these is a path that must
renew it."""

from __future__ import annotations

import json
import os
import sqlite3
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from app.server.recording import Recording
from app.server.storage import note_changed
from bench._clinic import Clinic, populate

N_SUBJECTS, PER_SUBJECT = 24, 3


@pytest.fixture
def clinic(tmp_path: Path) -> Iterator[tuple[TestClient, Clinic, Path]]:
    cl = populate(tmp_path, N_SUBJECTS, PER_SUBJECT, n_with_files=N_SUBJECTS * PER_SUBJECT)
    for part in (tmp_path / "recordings").glob("*/*"):  # as a transfer leaves them
        files = [{"name": f.name, "size": f.stat().st_size} for f in sorted(part.iterdir())]
        (part / "manifest.json").write_text(json.dumps({"files": files}))
    s = Settings(data_dir=tmp_path, viewer_enabled=False, node_token="test-node-token",
                 admin_password="secret-pw", storage_check_interval_s=0.5)
    with TestClient(create_app(s)) as c:
        r = c.post("/api/auth/login", json={"username": "admin", "password": "secret-pw"})
        c.headers["Authorization"] = f"Bearer {r.json()['token']}"
        for _ in range(400):  # the start-up measurement, in the background
            if c.get("/api/storage?subjects=false").json()["usage_scanned_at"]:
                break
            time.sleep(0.05)
        yield c, cl, tmp_path


# --------------------------------------------------------------- the slow, obvious way


def _rows(data: Path) -> list[tuple[int, int, str, int | None, str | None]]:
    """(subject, project, code, session, recording) of every row, from the file."""
    with sqlite3.connect(data / "gaitrig.sqlite3") as con:
        return con.execute(
            "SELECT s.id, s.project_id, s.code, se.id, r.id FROM subjects s "
            "LEFT JOIN sessions se ON se.subject_id = s.id "
            "LEFT JOIN recordings r ON r.session_id = se.id").fetchall()


def _disk_bytes(data: Path, rec_id: str) -> int:
    """Every file below the recording's folder and its references' folder."""
    total = 0
    for top in (data / "recordings" / rec_id, data / "references" / rec_id):
        for root, _dirs, files in os.walk(top):
            total += sum(os.path.getsize(os.path.join(root, f)) for f in files)
    return total


def _expected_overview(data: Path) -> list[dict[str, Any]]:
    subjects: dict[int, dict[str, Any]] = {}
    for sid, pid, code, _se, rec in _rows(data):
        d = subjects.setdefault(sid, {"id": sid, "project_id": pid, "code": code,
                                      "bytes": 0, "n_recordings": 0})
        if rec is not None:
            d["bytes"] += _disk_bytes(data, rec)
            d["n_recordings"] += 1
    return sorted(subjects.values(), key=lambda d: (d["project_id"], d["code"], d["id"]))


def _check_overview(c: TestClient, data: Path) -> list[dict[str, Any]]:
    r = c.get("/api/storage")
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["subjects"] == _expected_overview(data)
    # the same bytes FastAPI's own JSON response would have sent
    assert r.content == json.dumps(body, ensure_ascii=False, allow_nan=False,
                                   separators=(",", ":")).encode()
    assert r.headers["content-type"] == "application/json"
    assert set(body) == {"disk", "data_dir", "subjects", "pending_node_deletions",
                         "usage_scanned_at"}
    return list(body["subjects"])


def _check_lists(c: TestClient, data: Path) -> None:
    """The subjects page, the recordings page and every subject's sessions."""
    rows = _rows(data)
    sessions: dict[int, set[int]] = {}
    recs: dict[int, dict[int, set[str]]] = {}
    for sid, _pid, _code, se, rec in rows:
        sessions.setdefault(sid, set())
        recs.setdefault(sid, {})
        if se is not None:
            sessions[sid].add(se)
            recs[sid].setdefault(se, set())
            if rec is not None:
                recs[sid][se].add(rec)
    r = c.get("/api/subjects", params={"limit": 500})
    assert r.status_code == 200, r.text
    assert int(r.headers["X-Total-Count"]) == len(sessions)
    for s in r.json():
        ids = [i for x in recs[s["id"]].values() for i in x]
        assert (s["n_sessions"], s["n_recordings"], s["bytes_on_server"]) == (
            len(sessions[s["id"]]), len(ids), sum(_disk_bytes(data, i) for i in ids))
    for sid in sessions:
        r = c.get("/api/sessions", params={"subject_id": sid})
        assert r.status_code == 200, r.text
        assert {x["id"]: {y["id"] for y in x["recordings"]} for x in r.json()} == recs[sid]

    # the server's recordings newest first, as its list file keeps them
    live = c.app.state.hub.recordings.recordings  # type: ignore[attr-defined]
    newest = [x.id for x in sorted(live.values(), key=lambda x: x.created, reverse=True)]
    r = c.get("/api/recordings", params={"limit": 500})
    assert r.status_code == 200, r.text
    assert [x["id"] for x in r.json()] == newest[:500]
    assert int(r.headers["X-Total-Count"]) == len(newest)
    r = c.get("/api/recordings", params={"limit": 7, "offset": 5, "state": "complete"})
    complete = [x.id for x in sorted(live.values(), key=lambda x: x.created, reverse=True)
                if x.state == "complete"]
    assert [x["id"] for x in r.json()] == complete[5:12]


def _code_of(data: Path, rec_id: str) -> str:
    return next(code for _s, _p, code, _se, rec in _rows(data) if rec == rec_id)


# --------------------------------------------------------------------------- the tests


def test_lists_answer_what_the_rows_and_files_say(
        clinic: tuple[TestClient, Clinic, Path]) -> None:
    c, cl, data = clinic
    first = _check_overview(c, data)
    assert len(first) == N_SUBJECTS
    assert sum(x["n_recordings"] for x in first) == len(cl.recording_ids)
    assert all(x["bytes"] > 0 for x in first)
    assert _check_overview(c, data) == first  # kept: the same answer again
    _check_lists(c, data)


def test_a_recording_added_and_transferred(clinic: tuple[TestClient, Clinic, Path]) -> None:
    c, _cl, data = clinic
    before = _check_overview(c, data)
    # a new subject and session: rows written through the API
    r = c.post("/api/subjects", json={"project_id": 1, "code": "AAA001"})
    assert r.status_code == 201, r.text
    sid = r.json()["id"]
    r = c.post("/api/sessions", json={"subject_id": sid, "date": "2026-11-25"})
    assert r.status_code == 201, r.text
    sess = r.json()["id"]
    assert len(_check_overview(c, data)) == len(before) + 1

    # a recording the server made, filed under the session
    rec = Recording(id="R20261125-101500-new1", t_start=time.time() - 30,
                    t_stop=time.time() - 5)
    c.app.state.hub.recordings.recordings[rec.id] = rec  # type: ignore[attr-defined]
    r = c.post(f"/api/sessions/{sess}/recordings/attach", json={"rec_id": rec.id})
    assert r.status_code == 201, r.text
    now = {x["code"]: x for x in _check_overview(c, data)}
    assert (now["AAA001"]["n_recordings"], now["AAA001"]["bytes"]) == (1, 0)

    # its part arrives (the transfer manager reports a part it finished), and an older
    # recording gets a part of one more sensor, written deep in its folder
    part = data / "recordings" / rec.id / "S1"
    part.mkdir(parents=True)
    (part / "frames.bin").write_bytes(b"\0" * 4321)
    note_changed(part)  # app.server.transfer, when a part's transfer ends
    old = next(i for i in _cl.recording_ids if (data / "recordings" / i).is_dir())
    deep = next(p for p in (data / "recordings" / old).iterdir() if p.is_dir())
    (deep / "frames.bin").write_bytes((deep / "frames.bin").read_bytes() + b"\1" * 999)
    note_changed(deep / "frames.bin")
    now = {x["code"]: x for x in _check_overview(c, data)}
    assert now["AAA001"]["bytes"] == 4321
    _check_lists(c, data)


def test_a_recording_deleted(clinic: tuple[TestClient, Clinic, Path]) -> None:
    c, cl, data = clinic
    before = {x["code"]: x for x in _check_overview(c, data)}
    rec_id = cl.recording_ids[4]
    code = _code_of(data, rec_id)
    gone = _disk_bytes(data, rec_id)
    assert gone > 0
    r = c.post(f"/api/storage/recordings/{rec_id}/delete", json={"confirm": code})
    assert r.status_code == 200, r.text
    now = {x["code"]: x for x in _check_overview(c, data)}
    assert (now[code]["bytes"], now[code]["n_recordings"]) == (
        before[code]["bytes"] - gone, before[code]["n_recordings"] - 1)
    _check_lists(c, data)


def test_a_file_that_vanishes_is_found_by_the_periodic_check(
        clinic: tuple[TestClient, Clinic, Path]) -> None:
    c, cl, data = clinic
    before = {x["code"]: x for x in _check_overview(c, data)}
    rec_id = cl.recording_ids[7]
    code = _code_of(data, rec_id)
    frames = next((data / "recordings" / rec_id).glob("*/frames.bin"))
    size = frames.stat().st_size
    frames.unlink()  # deep in the folder: its stamp does not move
    ds = c.app.state.datasync  # type: ignore[attr-defined]
    deadline = time.monotonic() + 60
    while rec_id not in ds.found_damaged:
        assert time.monotonic() < deadline, "the periodic check did not find the file gone"
        time.sleep(0.1)
    now = {x["code"]: x for x in _check_overview(c, data)}
    assert now[code]["bytes"] == before[code]["bytes"] - size
    _check_lists(c, data)


def test_a_reference_uploaded_and_deleted_through_the_api(
        clinic: tuple[TestClient, Clinic, Path]) -> None:
    from tests.app.test_storage_cleanup import _skeleton_csv

    c, cl, data = clinic
    before = {x["code"]: x for x in _check_overview(c, data)}
    rec_id = cl.recording_ids[2]
    code = _code_of(data, rec_id)
    body = _skeleton_csv()
    r = c.post(f"/api/exports/{rec_id}/references",
               files={"file": ("walk.csv", body, "text/csv")})
    assert r.status_code == 201, r.text
    now = {x["code"]: x for x in _check_overview(c, data)}  # at once, not after 10 s
    assert now[code]["bytes"] == before[code]["bytes"] + len(body)
    r = c.post(f"/api/exports/{rec_id}/references/{r.json()['id']}/delete")
    assert r.status_code == 200, r.text
    assert {x["code"]: x for x in _check_overview(c, data)}[code] == before[code]
