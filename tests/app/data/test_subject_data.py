"""In-process tests of a subject's data as health data: deletion order and crash
consistency, refusals while a transfer runs, export, concurrent edits, audit trail."""

from __future__ import annotations

import inspect
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy.exc import OperationalError
from sqlalchemy.orm import Session as OrmSession

from app.config import Settings
from app.db import data as m
from app.main import create_app
from app.server.storage import StorageLayout
from tests.app.data.test_data_api import _calibrate, _make_part, _recording_row


def _client(data_dir: Path) -> TestClient:
    s = Settings(data_dir=data_dir, viewer_enabled=False, node_token="test-node-token",
                 admin_password="secret-pw")
    return TestClient(create_app(s), raise_server_exceptions=False)


def _login(c: TestClient) -> None:
    r = c.post("/api/auth/login", json={"username": "admin", "password": "secret-pw"})
    c.headers["Authorization"] = f"Bearer {r.json()['token']}"


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    with _client(tmp_path) as c:
        _login(c)
        yield c


def _planted(client: TestClient, tmp_path: Path) -> dict[str, Any]:
    """Subject A1 with a complete recording R1 whose part and a reference are on disk."""
    _make_part(tmp_path / "node-side", server=tmp_path)
    _recording_row(client)
    (tmp_path / "references" / "R1").mkdir(parents=True)
    (tmp_path / "references" / "R1" / "x.csv").write_text("time\n")
    subj = client.get("/api/subjects").json()[0]
    return subj  # type: ignore[no-any-return]


def _rows(client: TestClient) -> list[str]:
    with client.app.state.db_sessions() as db:  # type: ignore[attr-defined]
        return [r.id for r in db.query(m.Recording)]


def test_a_failed_commit_deletes_no_file(client: TestClient, tmp_path: Path,
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """The database refuses the deletion (locked, disk full): every file stays. While
    the rows are being deleted the backbone no longer knows the recording, so no
    transfer can start writing into it (the data sync starts one twice a second)."""
    from app.server.recording import Part, Recording

    subj = _planted(client, tmp_path)
    hub = client.app.state.hub  # type: ignore[attr-defined]
    hub.recordings.recordings["R1"] = Recording("R1", t_start=1.0, t_stop=2.0, parts={
        "S1": Part("S1", state="on_node", n_frames=10)})
    known_during_commit: list[bool] = []
    commit = OrmSession.commit

    def locked(self: OrmSession) -> None:
        # only the deletion's commit is refused: the data sync's own (twice a second, in
        # its thread) goes through, and whether it came during the request is luck
        if not any(f.function == "_commit_deletion" for f in inspect.stack(0)):
            return commit(self)
        known_during_commit.append("R1" in hub.recordings.recordings)
        raise OperationalError("COMMIT", {}, Exception("database is locked"))

    with monkeypatch.context() as mp:
        mp.setattr(OrmSession, "commit", locked)
        r = client.post(f"/api/subjects/{subj['id']}/delete", json={"confirm": "A1"})
    # a clear 503 that says nothing changed, not an "internal error"
    assert r.status_code == 503, r.text
    assert "nothing was changed" in r.json()["detail"]
    assert "locked" not in r.text and "COMMIT" not in r.text
    assert r.headers["retry-after"] == "30"
    assert known_during_commit == [False]
    assert "R1" in hub.recordings.recordings  # the rows survived: so does the live entry
    assert _rows(client) == ["R1"]
    assert (tmp_path / "recordings" / "R1" / "S1" / "frames.bin").is_file()
    assert (tmp_path / "references" / "R1" / "x.csv").is_file()
    assert StorageLayout(tmp_path).tombstones() == {}
    # and the deletion works afterwards
    r = client.post(f"/api/subjects/{subj['id']}/delete", json={"confirm": "A1"})
    assert r.status_code == 200, r.text
    assert not (tmp_path / "recordings" / "R1").exists()
    assert not (tmp_path / "references" / "R1").exists()
    assert "R1" not in hub.recordings.recordings
    assert hub.transfers.pending_deletions() == {"S1": ["R1"]}  # S1 is offline


def test_a_crash_after_the_commit_is_finished_at_the_next_start(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The server dies after the rows are gone but before the files: the next start
    deletes the files (no orphan health data, no 'unfiled' ghost)."""
    with _client(tmp_path) as c:
        _login(c)
        subj = _planted(c, tmp_path)

        def die(self: StorageLayout, rec_id: str) -> None:
            raise RuntimeError("power cut")

        with monkeypatch.context() as mp:
            mp.setattr(StorageLayout, "delete_recording", die)
            r = c.post(f"/api/subjects/{subj['id']}/delete", json={"confirm": "A1"})
        assert r.status_code == 500
        assert _rows(c) == []
        assert (tmp_path / "recordings" / "R1").is_dir()  # the crash left them
        assert set(StorageLayout(tmp_path).tombstones()) == {"R1"}
    with _client(tmp_path) as c:
        _login(c)
        assert not (tmp_path / "recordings" / "R1").exists()
        assert not (tmp_path / "references" / "R1").exists()
        assert StorageLayout(tmp_path).tombstones() == {}
        assert c.get("/api/storage/unfiled").json() == []


def test_a_tombstone_whose_rows_survived_deletes_nothing(tmp_path: Path) -> None:
    """The server died before the commit: the rows are there, so are the files."""
    with _client(tmp_path) as c:
        _login(c)
        _planted(c, tmp_path)
    StorageLayout(tmp_path).set_tombstones({"R1": ["S1"]})
    with _client(tmp_path) as c:
        _login(c)
        assert _rows(c) == ["R1"]
        assert (tmp_path / "recordings" / "R1" / "S1" / "frames.bin").is_file()
        assert StorageLayout(tmp_path).tombstones() == {}
        assert c.get("/api/storage").json()["pending_node_deletions"] == {}


def test_no_deletion_while_a_part_is_transferred(client: TestClient, tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """The database says 'complete' (mirrored twice a second) but a transfer runs."""
    subj = _planted(client, tmp_path)
    hub = client.app.state.hub  # type: ignore[attr-defined]
    monkeypatch.setattr(hub.transfers, "running_parts", lambda rec_id: {"S1"})
    r = client.post(f"/api/subjects/{subj['id']}/delete", json={"confirm": "A1"})
    assert r.status_code == 409 and "being transferred" in r.json()["detail"]
    assert (tmp_path / "recordings" / "R1" / "S1" / "frames.bin").is_file()
    assert _rows(client) == ["R1"]


def test_audit_trail_of_logins_exports_and_deletions(client: TestClient, tmp_path: Path
                                                     ) -> None:
    import sqlalchemy as sa

    from app.api.security import hash_password
    from app.db.models import User

    subj = _planted(client, tmp_path)
    with client.app.state.db_sessions() as db:  # type: ignore[attr-defined]
        db.add(User(username="=HYPERLINK(1)", password_hash=hash_password("pw-12345678")))
        db.commit()
    assert TestClient(client.app).post("/api/auth/login", json={
        "username": "=HYPERLINK(1)", "password": "x"}).status_code == 401
    # a password typed into the user name field is not kept
    assert TestClient(client.app).post("/api/auth/login", json={
        "username": "hunter2-secret", "password": "x"}).status_code == 401
    r = client.get("/api/exports/R1/skeleton", params={"format": "csv", "source": "S1"})
    assert r.status_code == 200
    r = client.post(f"/api/subjects/{subj['id']}/delete", json={"confirm": "A1"})
    assert r.status_code == 200
    log = client.get("/api/audit").json()
    got = [(e["username"], e["action"], e["target"]) for e in reversed(log)]
    assert got == [("admin", "login", ""), ("=HYPERLINK(1)", "login_failed", ""),
                   ("(unknown user)", "login_failed", ""),
                   ("admin", "export", "recording R1"),
                   ("admin", "delete", f"subject {subj['id']}")], got
    assert "1 recording" in log[0]["detail"] and log[0]["client"]
    assert all(e["at"] for e in log)
    # the trail names no deleted pseudonym
    assert "A1" not in str(log) and "hunter2" not in str(log)
    # append-only, down to the database
    with client.app.state.db_sessions() as db:  # type: ignore[attr-defined]
        for stmt in ("update audit_events set username = 'x'", "delete from audit_events"):
            with pytest.raises(sa.exc.DatabaseError, match="append-only"):
                db.execute(sa.text(stmt))
            db.rollback()
        db.add(User(username="nurse", password_hash=hash_password("nurse-pw-123"),
                    is_admin=False))
        db.commit()
    # CSV for the administrator (the download is recorded too); no formula in a cell
    r = client.get("/api/audit", params={"format": "csv"})
    assert r.status_code == 200 and "attachment" in r.headers["content-disposition"]
    assert "'=HYPERLINK(1)" in r.text and ",=HYPERLINK" not in r.text
    assert client.get("/api/audit").json()[0]["target"] == "audit trail"
    # not for other users
    nurse = TestClient(client.app)
    tok = nurse.post("/api/auth/login", json={"username": "nurse",
                                              "password": "nurse-pw-123"}).json()["token"]
    r = nurse.get("/api/audit", headers={"Authorization": f"Bearer {tok}"})
    assert r.status_code == 403 and "administrator" in r.json()["detail"]


def test_subject_export_is_complete_documented_and_authenticated(
        client: TestClient, tmp_path: Path) -> None:
    import io
    import json
    import zipfile

    from app.server.storage import read_part_skeleton
    from engine.io.csv import read_skeleton_csv

    subj = _planted(client, tmp_path)
    _calibrate(tmp_path, 0.3)  # so the export can analyse the recording
    client.post(f"/api/subjects/{subj['id']}/delete", json={"confirm": "nope"})
    assert TestClient(client.app).get(f"/api/subjects/{subj['id']}/export").status_code == 401
    assert client.get("/api/subjects/999/export").status_code == 404
    r = client.get(f"/api/subjects/{subj['id']}/export")
    assert r.status_code == 200 and r.headers["content-type"] == "application/zip"
    disp = r.headers["content-disposition"]
    assert disp.startswith('attachment; filename="gaitrig-subject-A1-') and disp.endswith('.zip"')
    z = zipfile.ZipFile(io.BytesIO(r.content))
    names = set(z.namelist())
    part = tmp_path / "recordings" / "R1" / "S1"
    for f in ("manifest.json", "meta.json", "index.json", "frames.bin"):
        assert z.read(f"recordings/R1/S1/{f}") == (part / f).read_bytes(), f
    assert z.read("references/R1/x.csv") == b"time\n"
    assert any(n.startswith("recordings/R1/analysis/") for n in names), names
    assert json.loads(z.read("recordings/R1/sensors.json"))["S1"]["T_world_sensor"]
    assert "README.txt" in names and b"skeleton.csv" in z.read("README.txt")
    info = json.loads(z.read("subject.json"))
    assert info["code"] == "A1" and info["project"]["name"] == "S"
    assert [r["id"] for s in info["sessions"] for r in s["recordings"]] == ["R1"]
    (tmp_path / "s.csv").write_bytes(z.read("recordings/R1/S1/skeleton.csv"))
    np_truth = read_part_skeleton(part)
    back = read_skeleton_csv(tmp_path / "s.csv")
    assert (back.times == np_truth.times).all()
    # the planted part holds no walk: its report is the only thing missing, and said so
    notes = json.loads(z.read("export-notes.json"))
    assert len(notes) == 1 and notes[0].startswith("reports/") and "walking" in notes[0], notes
    entry = client.get("/api/audit").json()[0]
    assert (entry["action"], entry["target"]) == ("export", f"subject {subj['id']}")


def test_the_export_streams_in_bounded_pieces(tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    import io
    import zipfile

    from app.server import storage

    monkeypatch.setattr(storage, "EXPORT_CHUNK", 64 * 1024)
    big = tmp_path / "frames.bin"
    big.write_bytes(bytes(range(256)) * 4096 * 3)  # 3 MiB
    pieces = list(storage.stream_zip([("a/frames.bin", big), ("b.json", b"{}"),
                                      ("skipped.csv", lambda: None)]))
    assert max(len(p) for p in pieces) <= 64 * 1024 + 1024
    assert sum(len(p) for p in pieces) > big.stat().st_size
    z = zipfile.ZipFile(io.BytesIO(b"".join(pieces)))
    assert z.namelist() == ["a/frames.bin", "b.json"]
    assert z.read("a/frames.bin") == big.read_bytes() and z.testzip() is None


def test_two_browsers_editing_one_subject(client: TestClient, tmp_path: Path) -> None:
    """The second save, based on a copy older than the first save, is refused (409);
    a save without a version (API scripts) still works; an edited note leaves no copy."""
    p = client.post("/api/projects", json={"name": "S"}).json()
    s = client.post("/api/subjects", json={"project_id": p["id"], "code": "A1",
                                           "notes": "Jane Roe-Wqxv"}).json()
    a = client.get(f"/api/subjects/{s['id']}").json()
    b = client.get(f"/api/subjects/{s['id']}").json()
    assert a["version"] == b["version"]
    r = client.patch(f"/api/subjects/{s['id']}", json={"notes": "", "version": a["version"]})
    assert r.status_code == 200 and r.json()["version"] != a["version"]
    r = client.patch(f"/api/subjects/{s['id']}", json={"height_m": 1.7, "version": b["version"]})
    assert r.status_code == 409 and "changed by someone else" in r.json()["detail"]
    assert client.get(f"/api/subjects/{s['id']}").json()["height_m"] is None
    assert client.patch(f"/api/subjects/{s['id']}", json={"height_m": 1.7}).status_code == 200
    for f in tmp_path.glob("gaitrig.sqlite3*"):
        assert b"Jane Roe-Wqxv" not in f.read_bytes(), f.name


def test_a_session_deleted_while_its_recording_starts(client: TestClient,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """The deletion commits between the start's lookup of the session and its own commit:
    409 with what happened (not a 500), and the orphan recording is stopped."""
    from app.server.recording import Recording

    p = client.post("/api/projects", json={"name": "S"}).json()
    s = client.post("/api/subjects", json={"project_id": p["id"], "code": "A1"}).json()
    sess = client.post("/api/sessions", json={"subject_id": s["id"]}).json()
    hub = client.app.state.hub  # type: ignore[attr-defined]
    stopped: list[str] = []

    def start(streams: list[str], image_every: int) -> Recording:
        with client.app.state.db_sessions() as db:  # type: ignore[attr-defined]
            db.delete(db.get(m.Session, sess["id"]))  # another browser's deletion
            db.commit()
        rec = Recording("R9", t_start=1.0)
        hub.recordings.recordings["R9"] = rec
        return rec

    monkeypatch.setattr(hub.recordings, "start", start)
    monkeypatch.setattr(hub.recordings, "stop", lambda rec_id: stopped.append(rec_id))
    r = client.post(f"/api/sessions/{sess['id']}/recordings", json={})
    assert r.status_code == 409 and "was deleted" in r.json()["detail"], r.text
    assert stopped == ["R9"] and _rows(client) == []


def test_an_edited_session_note_leaves_no_copy(client: TestClient, tmp_path: Path) -> None:
    p = client.post("/api/projects", json={"name": "S"}).json()
    s = client.post("/api/subjects", json={"project_id": p["id"], "code": "A1"}).json()
    sess = client.post("/api/sessions", json={"subject_id": s["id"],
                                              "notes": "came with Jane Roe-Wqxv"}).json()
    assert client.patch(f"/api/sessions/{sess['id']}", json={"notes": "came with her daughter"}
                        ).status_code == 200
    for f in tmp_path.glob("gaitrig.sqlite3*"):
        assert b"Jane Roe-Wqxv" not in f.read_bytes(), f.name


def test_a_recording_filed_under_no_session_can_be_deleted(client: TestClient,
                                                           tmp_path: Path) -> None:
    """Started from the Rig page and never filed: health data all the same."""
    from app.server.recording import Part, Recording

    _make_part(tmp_path / "node-side", server=tmp_path)
    hub = client.app.state.hub  # type: ignore[attr-defined]
    hub.recordings.recordings["R1"] = Recording("R1", t_start=1.0, t_stop=2.0, parts={
        "S1": Part("S1", state="complete", n_frames=60, on_server=True)})
    hub.recordings.recordings["R2"] = Recording("R2", t_start=3.0)  # still running
    assert [r["id"] for r in client.get("/api/storage/unfiled").json()] == ["R2", "R1"]
    # an export of it is refused with how to file it (not a bare "no recording")
    r = client.get("/api/exports/R1/skeleton", params={"format": "csv", "source": "S1"})
    assert r.status_code == 404
    assert "Subjects page" in r.json()["detail"]
    assert "/api/sessions/{session_id}/recordings/attach" in r.json()["detail"]
    r = client.post("/api/storage/unfiled/R1/delete", json={"confirm": "R"})
    assert r.status_code == 400 and "'R1'" in r.json()["detail"]
    assert (tmp_path / "recordings" / "R1" / "S1" / "frames.bin").is_file()
    r = client.post("/api/storage/unfiled/R2/delete", json={"confirm": "R2"})
    assert r.status_code == 409 and "running" in r.json()["detail"]
    assert client.post("/api/storage/unfiled/R7/delete", json={"confirm": "R7"}
                       ).status_code == 404
    r = client.post("/api/storage/unfiled/R1/delete", json={"confirm": "R1"})
    assert r.status_code == 200, r.text
    assert "offline" in r.json()["node_copies"]["S1"]
    assert not (tmp_path / "recordings" / "R1").exists()
    assert [x["id"] for x in client.get("/api/storage/unfiled").json()] == ["R2"]
    assert client.get("/api/storage").json()["pending_node_deletions"] == {"S1": ["R1"]}
    e = client.get("/api/audit").json()[0]
    assert (e["action"], e["target"]) == ("delete", "recording R1")
    # a filed recording is deleted from its subject (confirm = subject code) instead
    _recording_row(client)
    hub.recordings.recordings["R1"] = Recording("R1", t_start=1.0, t_stop=2.0)
    r = client.post("/api/storage/unfiled/R1/delete", json={"confirm": "R1"})
    assert r.status_code == 409 and "filed under a session" in r.json()["detail"]



def test_purge_gives_way_to_readers(tmp_path: Path) -> None:
    """A reader in the middle of a long request (a report) keeps the log busy: the purge
    gives up after its tries instead of holding every writer off; once the reader is
    done, the deleted row is gone from every file."""
    import sqlite3

    import sqlalchemy as sa

    from app.db.base import make_engine, purge_deleted

    eng = make_engine(tmp_path / "g.sqlite3")
    with eng.begin() as c:
        c.execute(sa.text("insert into projects (name, description, created_at) "
                          "values ('Jane Roe-Wqxv', '', '2026-01-01')"))
    reader = sqlite3.connect(tmp_path / "g.sqlite3")
    reader.execute("begin")
    reader.execute("select * from projects").fetchall()  # holds a snapshot
    with eng.begin() as c:
        c.execute(sa.text("delete from projects"))
    assert purge_deleted(eng, attempts=2, wait_s=0.0) is False
    with eng.begin() as c:  # writers were not locked out
        c.execute(sa.text("insert into projects (name, description, created_at) "
                          "values ('other', '', '2026-01-01')"))
    reader.rollback()
    reader.close()
    assert purge_deleted(eng) is True
    eng.dispose()
    for f in tmp_path.glob("g.sqlite3*"):
        assert b"Jane Roe-Wqxv" not in f.read_bytes(), f.name
