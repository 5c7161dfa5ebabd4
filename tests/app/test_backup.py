"""``gaitrig backup`` / ``restore``: an online backup of a running server (in process),
verification, restore into a fresh folder with the database migrated to the current
head, refusals with clear messages, and deletions that survive a restore of an older
backup (the erasure log)."""

from __future__ import annotations

import hashlib
import io
import json
import re
import sqlite3
import subprocess
import sys
import tarfile
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.cli import main
from app.config import Settings
from app.db import data as m
from app.main import create_app
from app.nodes.protocol import encode_skeletons
from app.nodes.store import NodeStore
from app.server import backup as bk
from app.server import erasures
from engine.skeleton import TrackingState
from tests.app.data.test_data_api import _sink_part

GONE = "QX4417"  # a distinctive code: a byte search of the restored files cannot hit else
KEEP = "KP0042"


def _head() -> str:
    from alembic.config import Config
    from alembic.script import ScriptDirectory

    cfg = Config()
    cfg.set_main_option("script_location", str(m.ALEMBIC_DIR))
    head = ScriptDirectory.from_config(cfg).get_current_head()
    assert head is not None
    return head


def _client(data_dir: Path) -> TestClient:
    s = Settings(data_dir=data_dir, viewer_enabled=False, node_token="test-node-token",
                 admin_password="secret-pw")
    c = TestClient(create_app(s))
    c.__enter__()
    r = c.post("/api/auth/login", json={"username": "admin", "password": "secret-pw"})
    c.headers["Authorization"] = f"Bearer {r.json()['token']}"
    return c


@pytest.fixture
def server(tmp_path: Path) -> Iterator[TestClient]:
    """A running server (in process) on ``tmp_path/var``."""
    c = _client(tmp_path / "var")
    yield c
    c.__exit__(None, None, None)


def _part(tmp: Path, data_dir: Path, rec_id: str, node: str, seed: int) -> None:
    """A node part of 30 frames copied into the data folder as a transfer would."""
    rng = np.random.default_rng(seed)
    store = NodeStore(tmp / "node" / node)
    w = store.create_part(rec_id, node_id=node,
                          clock_start={"offset_s": 0.0, "drift": 0.0, "t_ref": 0.0})
    for k in range(30):
        pos = rng.normal(0, 0.3, (1, 25, 3)) + np.array([0, 0, 2.5])
        st = np.full((1, 25), TrackingState.TRACKED, np.uint8)
        w.append(k / 30, "skeleton", encode_skeletons(k, k / 30, pos, st))
    w.close()
    _sink_part(store.root / rec_id, rec_id, node, data_dir)


def _subject(c: TestClient, data_dir: Path, tmp: Path, project_id: int, code: str,
             rec_id: str) -> dict[str, Any]:
    """A subject with one session and one complete recording (a part, a reference)."""
    s = c.post("/api/subjects", json={"project_id": project_id, "code": code,
                                      "notes": f"notes of {code}"}).json()
    sess = c.post("/api/sessions", json={"subject_id": s["id"]}).json()
    with c.app.state.db_sessions() as db:  # type: ignore[attr-defined]
        db.add(m.Recording(id=rec_id, session_id=sess["id"], state="complete", streams=""))
        db.add(m.RecordingPart(recording_id=rec_id, node_id="S1", state="complete",
                               n_frames=30))
        db.commit()
    _part(tmp, data_dir, rec_id, "S1", len(code))
    ref = data_dir / "references" / rec_id / "a1.csv"
    ref.parent.mkdir(parents=True)
    ref.write_text(f"reference of {rec_id}\n")
    return s


def _files(root: Path) -> dict[str, str]:
    """SHA-256 of every recording and reference file below a data folder."""
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for d in ("recordings", "references") for p in sorted((root / d).rglob("*"))
            if p.is_file()}


def _cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture
def archive(server: TestClient, tmp_path: Path) -> Path:
    """A backup of the running server (``tmp_path/var``, no subjects) at ``tmp_path/b.tar``."""
    return bk.create_backup(tmp_path / "var", tmp_path / "b.tar").path


def _refused(capsys: pytest.CaptureFixture[str], archive: Path, dest: Path,
             *flags: str) -> str:
    """Run ``gaitrig restore ARCHIVE --data-dir DEST --without-deletion-log [flags]``,
    check that it is refused (exit code 2) and return what it printed on stderr."""
    code, _o, err = _cli(capsys, "restore", str(archive), "--data-dir", str(dest),
                         "--without-deletion-log", *flags)
    assert code == 2, err
    assert err.startswith("gaitrig restore: error: ") and err.count("\n") == 1, err
    return err


def _subjects(c: TestClient) -> list[tuple[str, list[str]]]:
    out = []
    for s in c.get("/api/subjects").json():
        full = c.get(f"/api/subjects/{s['id']}").json()
        out.append((s["code"], [r["id"] for x in full["sessions"] for r in x["recordings"]]))
    return sorted(out)


def test_round_trip_of_a_running_server(server: TestClient, tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    var = tmp_path / "var"
    assert server.get("/api/system").json()["last_backup_at"] is None
    p = server.post("/api/projects", json={"name": "Study"}).json()
    _subject(server, var, tmp_path, p["id"], KEEP, "R20260101-100000-aaaa")
    _subject(server, var, tmp_path, p["id"], "KP0043", "R20260101-110000-bbbb")
    # a part still arriving: left out and named
    (var / "recordings" / "R20260101-110000-bbbb" / "S2" / ".incoming").mkdir(parents=True)
    before = _subjects(server)
    dest = tmp_path / "backups"
    dest.mkdir()
    code, out, err = _cli(capsys, "backup", str(dest), "--data-dir", str(var))
    assert code == 0, err
    archive = next(dest.glob("gaitrig-backup-*.tar"))
    assert "2 subjects, 2 recordings" in out
    assert "left out: recordings/R20260101-110000-bbbb/S2: part still being transferred" in out
    man = bk.verify_backup(archive).manifest
    assert man["alembic_revision"] == _head() and man["counts"]["subjects"] == 2
    assert man["gaitrig_version"] and man["created_at"] and all(
        len(e["sha256"]) == 64 for e in man["members"])
    assert (archive.stat().st_mode & 0o777) == 0o600
    # the backup is an audit event and the console learns its time
    at = server.get("/api/system").json()["last_backup_at"]
    assert at is not None and at[:10] == man["created_at"][:10]
    ev = server.get("/api/audit", params={"action": "backup"}).json()
    ev = ev.get("events", ev) if isinstance(ev, dict) else ev
    assert ev and ev[0]["target"] == archive.name and "(command line)" in ev[0]["username"]

    code, out, err = _cli(capsys, "backup", "--verify", str(archive))
    assert code == 0 and "every checksum matches" in out, err
    fresh = tmp_path / "fresh"
    code, out, err = _cli(capsys, "restore", str(archive), "--data-dir", str(fresh),
                          "--deletion-log", str(var))
    assert code == 0, err
    assert f"revision {_head()} -> {_head()}" in out
    assert _files(fresh) == {k: v for k, v in _files(var).items() if "/S2/" not in k}
    c2 = _client(fresh)
    try:
        assert _subjects(c2) == before
        r = c2.get("/api/storage/recordings/R20260101-100000-aaaa").json()
        assert r["state"] == "complete" and r["bytes_on_server"] > 0
        ev = c2.get("/api/audit", params={"action": "restore"}).json()
        ev = ev.get("events", ev) if isinstance(ev, dict) else ev
        assert ev and ev[0]["target"] == archive.name
    finally:
        c2.__exit__(None, None, None)


def _flip(archive: Path, member: str) -> None:
    with tarfile.open(archive) as tar:
        off = tar.getmember(member).offset_data
    with open(archive, "r+b") as fh:
        fh.seek(off + 10)
        b = fh.read(1)
        fh.seek(off + 10)
        fh.write(bytes([b[0] ^ 0xFF]))


def test_verify_detects_a_damaged_file_and_restore_refuses_it(
        server: TestClient, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    var = tmp_path / "var"
    p = server.post("/api/projects", json={"name": "Study"}).json()
    _subject(server, var, tmp_path, p["id"], KEEP, "R20260101-100000-aaaa")
    archive = bk.create_backup(var, tmp_path / "b.tar").path
    frames = "files/recordings/R20260101-100000-aaaa/S1/frames.bin"
    _flip(archive, frames)
    code, _out, err = _cli(capsys, "backup", "--verify", str(archive))
    assert code == 1 and f"{frames}: checksum mismatch" in err
    fresh = tmp_path / "fresh"
    code, _out, err = _cli(capsys, "restore", str(archive), "--data-dir", str(fresh),
                           "--without-deletion-log")
    assert code == 2 and "is damaged; nothing was restored" in err and frames in err
    assert not fresh.exists() or not any(fresh.iterdir())
    assert not list(tmp_path.glob(".fresh.restoring-*"))  # the staging folder is gone


def test_restore_refuses_a_non_empty_folder_and_wrong_archives(
        server: TestClient, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    var = tmp_path / "var"
    archive = bk.create_backup(var, tmp_path / "b.tar").path
    full = tmp_path / "full"
    full.mkdir()
    (full / "notes.txt").write_text("mine")
    code, _o, err = _cli(capsys, "restore", str(archive), "--data-dir", str(full),
                         "--without-deletion-log")
    assert code == 2 and "is not empty" in err and "--force" in err
    assert [p.name for p in full.iterdir()] == ["notes.txt"]
    # without the current erasure log the restore does not start, and says why
    code, _o, err = _cli(capsys, "restore", str(archive), "--data-dir", str(tmp_path / "x"))
    assert code == 2 and "--deletion-log" in err and "bring that subject back" in err
    assert not (tmp_path / "x").exists()
    # a subject export (zip), a tar of something else, a missing file
    z = tmp_path / "export.zip"
    with zipfile.ZipFile(z, "w") as zf:
        zf.writestr("subject.json", "{}")
    other = tmp_path / "other.tar"
    with tarfile.open(other, "w") as tar:
        tar.addfile(tarfile.TarInfo("hello.txt"), io.BytesIO(b""))
    for bad, msg in [(z, "is not a gaitrig backup (not an uncompressed tar"),
                     (other, "is not a gaitrig backup (no readable gaitrig-backup.json"),
                     (tmp_path / "nope.tar", "no backup archive at")]:
        code, _o, err = _cli(capsys, "restore", str(bad), "--data-dir", str(tmp_path / "y"),
                             "--without-deletion-log")
        assert code == 2 and msg in err, err
        code, _o, err = _cli(capsys, "backup", "--verify", str(bad))
        assert code == 2 and msg in err, err
    # --force replaces (never merges): the old file is gone afterwards
    code, _o, err = _cli(capsys, "restore", str(archive), "--data-dir", str(full),
                         "--without-deletion-log", "--force")
    assert code == 0, err
    assert not (full / "notes.txt").exists() and (full / "gaitrig.sqlite3").is_file()
    # not while a server (another process) has the folder's database open
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sqlite3, sys; c = sqlite3.connect(sys.argv[1]); "
         "c.execute('pragma journal_mode=WAL'); c.execute('select 1').fetchall(); "
         "print('open', flush=True); sys.stdin.read()", str(full / "gaitrig.sqlite3")],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "open"
        code, _o, err = _cli(capsys, "restore", str(archive), "--data-dir", str(full),
                             "--without-deletion-log", "--force")
        assert code == 2 and "open in another program" in err and "stop the server" in err
    finally:
        holder.communicate("", timeout=10)
    # a backup never overwrites, nor goes into the data folder
    code, _o, err = _cli(capsys, "backup", str(archive), "--data-dir", str(var))
    assert code == 2 and "exists already" in err
    code, _o, err = _cli(capsys, "backup", str(var / "b.tar"), "--data-dir", str(var))
    assert code == 2 and "inside the data folder" in err


def _traces(root: Path, needle: str) -> list[str]:
    return [str(p.relative_to(root)) for p in sorted(root.rglob("*"))
            if needle in p.name or (p.is_file() and needle.encode() in p.read_bytes())]


def test_a_deleted_subject_stays_deleted_after_restoring_an_older_backup(
        server: TestClient, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    var = tmp_path / "var"
    p = server.post("/api/projects", json={"name": "Study"}).json()
    _subject(server, var, tmp_path, p["id"], KEEP, "R20260101-100000-aaaa")
    gone = _subject(server, var, tmp_path, p["id"], GONE, "R20260101-110000-gone")
    old = bk.create_backup(var, tmp_path / "before-deletion.tar").path
    r = server.post(f"/api/subjects/{gone['id']}/delete", json={"confirm": GONE})
    assert r.status_code == 200, r.text
    # SQLite gives the next subject the deleted one's id: it must not be taken for it
    new = server.post("/api/subjects", json={"project_id": p["id"], "code": "NW0001"}).json()
    assert new["id"] == gone["id"]
    # the log names no pseudonym and not even the recording's id (only an unkeyed hash)
    log = (var / "erasures.jsonl").read_text()
    assert GONE not in log and "R20260101-110000-gone" not in log
    assert erasures.rec_key("R20260101-110000-gone") in log

    # 1) the old backup restored with the server's current erasure log
    a = tmp_path / "a"
    code, out, err = _cli(capsys, "restore", str(old), "--data-dir", str(a),
                          "--deletion-log", str(var / "erasures.jsonl"))
    assert code == 0, err
    assert "1 deleted recording kept deleted" in out
    assert _traces(a, GONE) == []  # not in the database file, not in any file name
    assert not (a / "recordings" / "R20260101-110000-gone").exists()
    assert not (a / "references" / "R20260101-110000-gone").exists()
    c = _client(a)
    try:
        assert _subjects(c) == [(KEEP, ["R20260101-100000-aaaa"])]
        # the server finished the rest of the deletion when it started (tombstones)
        assert json.loads((a / "deletions.json").read_text()) == {}
    finally:
        c.__exit__(None, None, None)
    # ... and the next backup of the restored server carries the log on
    assert erasures.rec_key("R20260101-110000-gone") in (a / "erasures.jsonl").read_text()

    # 2) a newer backup serves as the log (the data folder was lost with the server)
    newer = bk.create_backup(var, tmp_path / "after-deletion.tar").path
    b = tmp_path / "b"
    code, _o, err = _cli(capsys, "restore", str(old), "--data-dir", str(b),
                         "--deletion-log", str(newer))
    assert code == 0, err
    assert _traces(b, GONE) == []
    # 3) the newer backup restored: the later subject with the reused id is kept
    n = tmp_path / "n"
    code, _o, err = _cli(capsys, "restore", str(newer), "--data-dir", str(n),
                         "--deletion-log", str(var))
    assert code == 0, err
    with sqlite3.connect(n / "gaitrig.sqlite3") as db:
        codes = sorted(r[0] for r in db.execute("select code from subjects"))
    assert codes == [KEEP, "NW0001"]
    # 4) without a log, only on the operator's word: the subject is back (and said so)
    w = tmp_path / "w"
    code, out, err = _cli(capsys, "restore", str(old), "--data-dir", str(w),
                          "--without-deletion-log")
    assert code == 0 and "WARNING: restored without the current erasure log" in out
    with sqlite3.connect(w / "gaitrig.sqlite3") as db:
        assert GONE in [r[0] for r in db.execute("select code from subjects")]
        detail = db.execute("select detail from audit_events where action='restore'"
                            ).fetchone()[0]
    assert "WITHOUT a current erasure log" in detail


def _old_database(data_dir: Path) -> None:
    """A data folder whose database is at alembic revision 0001 (an older release)."""
    from alembic.config import Config

    import app.db.models  # noqa: F401
    from alembic import command
    from app.db.base import Base

    data_dir.mkdir(parents=True)
    eng = sa.create_engine(f"sqlite:///{data_dir / 'gaitrig.sqlite3'}")
    Base.metadata.create_all(eng, tables=[t for n, t in Base.metadata.tables.items()
                                          if n not in m.DATA_TABLES])
    cfg = Config()
    cfg.set_main_option("script_location", str(m.ALEMBIC_DIR))
    with eng.begin() as conn:
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, "0001")
    with eng.begin() as conn:
        t = "'2025-05-01 10:00:00.000000'"
        conn.execute(sa.text(f"insert into projects (id, name, description, created_at) "
                             f"values (1, 'Old study', '', {t})"))
        conn.execute(sa.text(f"insert into subjects (id, project_id, code, sex, notes, "
                             f"created_at) values (1, 1, 'OLD001', 'unknown', '', {t})"))
        conn.execute(sa.text(f"insert into sessions (id, subject_id, date, label, notes, "
                             f"created_at) values (1, 1, '2025-05-01', 'baseline', '', {t})"))
        conn.execute(sa.text(f"insert into recordings (id, session_id, label, notes, state, "
                             f"streams, created_at) values ('R20250501-100000-0001', 1, '', "
                             f"'', 'complete', '', {t})"))
        conn.execute(sa.text(f"insert into recording_parts (recording_id, node_id, state, "
                             f"n_frames, bytes_total, bytes_done, attempts, updated_at) "
                             f"values ('R20250501-100000-0001', 'S1', 'complete', 30, 0, 0, "
                             f"1, {t})"))
    eng.dispose()


def test_a_backup_of_an_older_release_is_migrated_on_restore(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    old = tmp_path / "old"
    _old_database(old)
    _part(tmp_path, old, "R20250501-100000-0001", "S1", 3)
    archive = bk.create_backup(old, tmp_path / "old.tar").path  # the database untouched
    assert bk.verify_backup(archive).manifest["alembic_revision"] == "0001"
    fresh = tmp_path / "fresh"
    code, out, err = _cli(capsys, "restore", str(archive), "--data-dir", str(fresh),
                          "--without-deletion-log")
    assert code == 0, err
    assert f"revision 0001 -> {_head()}" in out
    c = _client(fresh)
    try:
        assert _subjects(c) == [("OLD001", ["R20250501-100000-0001"])]
        r = c.get("/api/storage/recordings/R20250501-100000-0001").json()
        assert r["parts"][0]["state"] == "complete" and r["bytes_on_server"] > 0
    finally:
        c.__exit__(None, None, None)
    with sqlite3.connect(fresh / "gaitrig.sqlite3") as db:
        cols = [r[1] for r in db.execute("pragma table_info(recording_parts)")]
    assert "images_skipped" in cols  # revision 0002 ran


def test_postgres_archives_hold_the_files_and_say_what_to_do(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    var = tmp_path / "var"
    var.mkdir()
    (var / "calibrations").mkdir()
    (var / "calibrations" / "v1.json").write_text("{}")
    res = bk.create_backup(var, tmp_path / "pg.tar",
                           "postgresql+psycopg://gaitrig:pw@db.invalid/gaitrig")
    assert res.manifest["database"]["member"] is None
    assert any("pg_dump" in n for n in res.manifest["notes"])
    assert bk.verify_backup(res.path).ok
    # restoring it needs the database restored with pg_restore first
    with pytest.raises(bk.BackupError, match="pg_restore"):
        bk.restore_backup(res.path, tmp_path / "r", [], without_deletion_log=True)


def test_verify_and_restore_check_the_database_integrity(
        server: TestClient, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    var = tmp_path / "var"
    p = server.post("/api/projects", json={"name": "Study"}).json()
    _subject(server, var, tmp_path, p["id"], KEEP, "R20260101-100000-aaaa")
    good = bk.create_backup(var, tmp_path / "good.tar").path
    # an archive whose checksums all match but whose database is damaged inside (as if
    # it had been damaged before it was hashed)
    bad = tmp_path / "bad.tar"
    with tarfile.open(good) as src, tarfile.open(bad, "w") as dst:
        man = json.loads(src.extractfile(bk.MANIFEST).read())  # type: ignore[union-attr]
        for info in src.getmembers():
            data = src.extractfile(info).read()  # type: ignore[union-attr]
            if info.name == bk.DB_MEMBER:
                page = 4096
                data = data[:page * 2] + b"\xff" * 64 + data[page * 2 + 64:]
                for e in man["members"]:
                    if e["name"] == info.name:
                        e["sha256"] = hashlib.sha256(data).hexdigest()
            if info.name == bk.MANIFEST:
                data = json.dumps(man).encode()
            info.size = len(data)
            dst.addfile(info, io.BytesIO(data))
    code, _o, err = _cli(capsys, "backup", "--verify", str(bad))
    assert code == 1 and "integrity_check" in err, err
    code, _o, err = _cli(capsys, "restore", str(bad), "--data-dir", str(tmp_path / "r"),
                         "--without-deletion-log")
    assert code == 2 and "fails PRAGMA integrity_check" in err, err
    assert not (tmp_path / "r").exists()


def test_erasure_log_entries_settle_after_a_crash_and_void_ones_are_not_applied(
        server: TestClient, tmp_path: Path) -> None:
    var = tmp_path / "var"
    p = server.post("/api/projects", json={"name": "Study"}).json()
    a = _subject(server, var, tmp_path, p["id"], KEEP, "R20260101-100000-aaaa")
    b = _subject(server, var, tmp_path, p["id"], GONE, "R20260101-110000-gone")
    with server.app.state.db_sessions() as db:  # type: ignore[attr-defined]
        sa_, sb = db.get(m.Subject, a["id"]), db.get(m.Subject, b["id"])
        # a deletion logged, then the server died before its commit: the rows survive
        e1 = erasures.begin(var, [], sa_, {})
        # one logged and committed, then the server died before it wrote "done"
        e2 = erasures.begin(var, [], sb, {"R20260101-110000-gone": ["S1"]})
        db.delete(sb)
        db.commit()
        assert erasures.settle(db, var) == 2
        states = {e.id: e.state for e in erasures.read(var)}
        assert states == {e1: "void", e2: "done"}
        assert erasures.settle(db, var) == 0  # settled once
    # a restore applies the done one only
    log = (var / "erasures.jsonl").read_text()
    assert KEEP not in log and GONE not in log
    archive = bk.create_backup(var, tmp_path / "b.tar").path
    res = bk.restore_backup(archive, tmp_path / "r", [var])
    assert res.erased_recordings == ["R20260101-110000-gone"]
    with sqlite3.connect(tmp_path / "r" / "gaitrig.sqlite3") as c:
        assert [r[0] for r in c.execute("select code from subjects")] == [KEEP]
    # a log cut short by a crash while appending its last line is read up to it; damage
    # elsewhere is named
    cut = tmp_path / "cut.jsonl"
    cut.write_text(log + '{"id": "x", "sta')
    assert len(bk.read_erasure_log(cut)) == 2
    cut.write_text('{"id": "x", "sta\n' + log)
    with pytest.raises(bk.BackupError, match="line 1: not an erasure log entry"):
        bk.read_erasure_log(cut)


def test_a_deleted_unfiled_recording_stays_deleted(server: TestClient, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """A recording filed under no session (Rig page) has no row: only its files and the
    hub's live entry (recordings.json) bring it back, and the restore removes both."""
    from app.server.recording import Part, Recording

    var = tmp_path / "var"
    rid = "R20260101-120000-unfd"
    hub = server.app.state.hub  # type: ignore[attr-defined]
    hub.recordings.recordings[rid] = Recording(id=rid, t_start=1.0, t_stop=2.0,
                                               parts={"S1": Part("S1", state="complete")})
    hub.recordings.save()
    _part(tmp_path, var, rid, "S1", 5)
    old = bk.create_backup(var, tmp_path / "old.tar").path
    r = server.post(f"/api/storage/unfiled/{rid}/delete", json={"confirm": rid})
    assert r.status_code == 200, r.text
    assert rid not in (var / "erasures.jsonl").read_text()
    a = tmp_path / "a"
    code, out, err = _cli(capsys, "restore", str(old), "--data-dir", str(a),
                          "--deletion-log", str(var))
    assert code == 0, err
    assert "1 deleted recording kept deleted" in out
    assert not (a / "recordings" / rid).exists()
    assert json.loads((a / "deletions.json").read_text()) == {rid: ["S1"]}
    c = _client(a)  # the server finishes it: the live entry goes, the node is asked
    try:
        assert c.get("/api/storage/unfiled").json() == []
        assert rid not in (a / "recordings.json").read_text()
        assert c.get("/api/storage").json()["pending_node_deletions"] == {"S1": [rid]}
    finally:
        c.__exit__(None, None, None)


def test_a_deleted_reference_stays_deleted_after_restoring_an_older_backup(
        server: TestClient, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Deleting a reference (an imported one, a report's) was not in the erasure log: a
    restore of a backup made before brought it back. A later upload is kept."""
    from app.api.routes import reports
    from app.server import storage

    var = tmp_path / "var"
    rid = "R20260101-100000-aaaa"
    p = server.post("/api/projects", json={"name": "Study"}).json()
    _subject(server, var, tmp_path, p["id"], KEEP, rid)
    with server.app.state.db_sessions() as db:  # type: ignore[attr-defined]
        ref = m.ReferenceImport(recording_id=rid, filename="vicon.c3d", format="c3d",
                                stored_name="b2.c3d")
        db.add(ref)
        db.commit()
        ref_id = ref.id
    (var / "references" / rid / "b2.c3d").write_bytes(b"vicon of " + GONE.encode())
    # (the file is no C3D: its reader, run first by both pages' check, is faked as well)
    monkeypatch.setattr(reports.an, "reference_steps", lambda path, **_: [1.0, 2.0, 3.0])
    monkeypatch.setattr(storage, "parse_reference", lambda path, fmt: None)

    def attach(data: bytes) -> None:
        r = server.post(f"/api/reports/recordings/{rid}/reference",
                        files={"file": ("walk.c3d", data, "application/octet-stream")})
        assert r.status_code == 201, r.text

    attach(b"report reference of " + GONE.encode())
    old = bk.create_backup(var, tmp_path / "old.tar").path
    # a report reference is backed up (its meta.json made it look like a part in transfer)
    with tarfile.open(old) as tar:
        assert f"files/recordings/{rid}/reference/reference.c3d" in tar.getnames()
    r = server.post(f"/api/exports/{rid}/references/{ref_id}/delete")
    assert r.status_code == 200, r.text
    r = server.delete(f"/api/reports/recordings/{rid}/reference")
    assert r.status_code == 200 and not r.json()["attached"], r.text
    assert _traces(var, GONE) == []
    log = (var / "erasures.jsonl").read_text()
    assert rid not in log and "b2.c3d" not in log and log.count('"done"') == 2
    assert [len(e.references) for e in erasures.read(var)] == [0, 1]

    a = tmp_path / "a"
    code, out, err = _cli(capsys, "restore", str(old), "--data-dir", str(a),
                          "--deletion-log", str(var))
    assert code == 0, err
    # said beside the recordings, as in the audit entry
    assert "0 deleted recordings kept deleted, 2 deleted references deleted again" in out
    assert _traces(a, GONE) == []  # neither file nor row is back
    assert (a / "references" / rid / "a1.csv").is_file()  # the other reference stays
    with sqlite3.connect(a / "gaitrig.sqlite3") as db:
        assert db.execute("select count(*) from reference_imports").fetchone()[0] == 0
        detail = db.execute("select detail from audit_events where action='restore'"
                            ).fetchone()[0]
    assert "2 deleted references" in detail

    # a reference uploaded after the deletion is not the deleted one
    attach(b"a later upload")
    newer = bk.create_backup(var, tmp_path / "newer.tar").path
    n = tmp_path / "n"
    code, _o, err = _cli(capsys, "restore", str(newer), "--data-dir", str(n),
                         "--deletion-log", str(var))
    assert code == 0, err
    assert (n / "recordings" / rid / "reference" / "reference.c3d").read_bytes() == (
        b"a later upload")


def test_a_reference_deletion_cut_short_by_a_crash_settles_by_what_is_left(
        server: TestClient, tmp_path: Path) -> None:
    var = tmp_path / "var"
    rid = "R20260101-100000-aaaa"
    folder = var / "recordings" / rid / "reference"
    folder.mkdir(parents=True)
    (folder / "meta.json").write_text(json.dumps({"uploaded": "2026-01-01T10:00:00+00:00"}))
    e1 = erasures.begin(var, [], None, {}, [(rid, "2026-01-01T10:00:00+00:00")])
    e2 = erasures.begin(var, [], None, {}, [(rid, "2025-12-31T10:00:00+00:00")])
    with server.app.state.db_sessions() as db:  # type: ignore[attr-defined]
        assert erasures.settle(db, var) == 2
    assert {e.id: e.state for e in erasures.read(var)} == {e1: "void", e2: "done"}


def test_a_failed_swap_with_force_leaves_the_old_folder_as_it_was(
        server: TestClient, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """--force deleted the old folder's contents before moving the restored ones in: a
    failure while moving (another disk, a full disk, a crash) lost both."""
    var = tmp_path / "var"
    p = server.post("/api/projects", json={"name": "Study"}).json()
    _subject(server, var, tmp_path, p["id"], KEEP, "R20260101-100000-aaaa")
    archive = bk.create_backup(var, tmp_path / "b.tar").path
    full = tmp_path / "full"
    (full / "recordings" / "R1").mkdir(parents=True)
    (full / "recordings" / "R1" / "x.bin").write_bytes(b"only copy")
    (full / "notes.txt").write_text("mine")
    real = bk.os.replace

    def flaky(src: Any, dst: Any) -> None:
        if Path(dst) == full / "gaitrig.sqlite3":  # the restored database into place
            raise OSError(18, "Invalid cross-device link", str(dst))
        real(src, dst)

    monkeypatch.setattr(bk.os, "replace", flaky)
    code, _o, err = _cli(capsys, "restore", str(archive), "--data-dir", str(full),
                         "--without-deletion-log", "--force")
    monkeypatch.undo()
    assert code == 2 and "cross-device" in err, err
    assert sorted(q.name for q in full.iterdir()) == ["notes.txt", "recordings"]
    assert _files(full) == {"recordings/R1/x.bin": hashlib.sha256(b"only copy").hexdigest()}
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_restore_into_a_mount_point(server: TestClient, tmp_path: Path,
                                    capsys: pytest.CaptureFixture[str]) -> None:
    """The docker set-up's data folder (/data) is a volume: its parent is another file
    system, so a staging folder beside it cannot be renamed into it."""
    from tests.tmpfs import mounted_tmpfs

    var = tmp_path / "var"
    p = server.post("/api/projects", json={"name": "Study"}).json()
    _subject(server, var, tmp_path, p["id"], KEEP, "R20260101-100000-aaaa")
    archive = bk.create_backup(var, tmp_path / "b.tar").path
    with mounted_tmpfs(tmp_path / "mnt", "64m") as mnt:
        (mnt / "old.txt").write_text("old")
        code, _o, err = _cli(capsys, "restore", str(archive), "--data-dir", str(mnt),
                             "--without-deletion-log", "--force")
        assert code == 0, err
        assert _files(mnt) == _files(var) and (mnt / "gaitrig.sqlite3").is_file()
        assert not (mnt / "old.txt").exists()
        assert not [q for q in mnt.iterdir() if q.name.startswith(".")]


def _evil(tmp_path: Path, archive: Path, name: str, add: Any) -> Path:
    """``archive`` with one more member, ``add(tar, name)``, listed in its manifest."""
    out = tmp_path / "evil.tar"
    out.unlink(missing_ok=True)
    with tarfile.open(archive) as src, tarfile.open(out, "w", format=tarfile.PAX_FORMAT) as dst:
        man = json.loads(src.extractfile(bk.MANIFEST).read())  # type: ignore[union-attr]
        for info in src.getmembers():
            if info.name != bk.MANIFEST:
                dst.addfile(info, src.extractfile(info))
        size, sha = add(dst, name)
        man["members"].append({"name": name, "size": size, "sha256": sha})
        data = json.dumps(man).encode()
        dst.addfile(_info(bk.MANIFEST, len(data)), io.BytesIO(data))
    return out


def _info(name: str, size: int) -> tarfile.TarInfo:
    i = tarfile.TarInfo(name)
    i.size = size
    return i


def test_restore_refuses_members_that_are_not_plain_files_or_leave_the_folder(
        archive: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:

    def link(kind: bytes, target: str) -> Any:
        def add(tar: tarfile.TarFile, name: str) -> tuple[int, str]:
            i = tarfile.TarInfo(name)
            i.type, i.linkname = kind, target
            tar.addfile(i)
            return 0, hashlib.sha256(b"").hexdigest()
        return add

    def plain(tar: tarfile.TarFile, name: str) -> tuple[int, str]:
        tar.addfile(_info(name, 3), io.BytesIO(b"abc"))
        return 3, hashlib.sha256(b"abc").hexdigest()

    def sparse(tar: tarfile.TarFile, name: str) -> tuple[int, str]:
        # a sparse member: a few header bytes that unpack to 256 MiB of zeros (a small
        # archive that fills the disk while it is unpacked, before any checksum)
        i = _info(name, 0)
        i.pax_headers = {"GNU.sparse.map": "0,0", "GNU.sparse.size": str(256 << 20)}
        tar.addfile(i, io.BytesIO(b""))
        return 256 << 20, "0" * 64

    for name, add, msg in [
            ("files/link", link(tarfile.SYMTYPE, "/etc/passwd"), "not a regular file"),
            ("files/hard", link(tarfile.LNKTYPE, "/etc/passwd"), "not a regular file"),
            ("files/dev", link(tarfile.CHRTYPE, ""), "not a regular file"),
            ("files/../../escape.txt", plain, "unsafe path"),
            ("/tmp/abs.txt", plain, "unsafe path"),
            ("files/big.bin", sparse, "a sparse file")]:
        bad = _evil(tmp_path, archive, name, add)
        dest = tmp_path / "r"
        assert msg in _refused(capsys, bad, dest), name
        assert not dest.exists() and not (tmp_path / "escape.txt").exists()
        assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")], name



def test_a_damaged_manifest_is_refused_in_words(
        archive: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The manifest is the one member no checksum covers: fields of the wrong shape
    raised KeyError/TypeError tracebacks from verify and restore."""
    with tarfile.open(archive) as tar:
        good = json.loads(tar.extractfile(bk.MANIFEST).read())  # type: ignore[union-attr]
    for k, (field, value) in enumerate([("database", None), ("members", {"a": 1}),
                                        ("members", [{"name": "x"}]), ("skipped", None),
                                        ("created_at", None), ("counts", []),
                                        ("notes", "x"), ("alembic_revision", [])]):
        man = {**good, field: value}
        if value is None:
            del man[field]
        bad = tmp_path / f"bad{k}.tar"
        with tarfile.open(archive) as src, tarfile.open(bad, "w") as dst:
            for info in src.getmembers():
                data = src.extractfile(info).read()  # type: ignore[union-attr]
                if info.name == bk.MANIFEST:
                    data = json.dumps(man).encode()
                dst.addfile(_info(info.name, len(data)), io.BytesIO(data))
        code, _o, err = _cli(capsys, "backup", "--verify", str(bad))
        assert code == 2 and f"damaged {bk.MANIFEST}" in err and field in err, (field, err)
        assert f"damaged {bk.MANIFEST}" in _refused(capsys, bad, tmp_path / "r"), field
        assert not (tmp_path / "r").exists()


def test_force_over_a_folder_whose_erasure_log_is_damaged_is_refused_in_words(
        archive: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    full = tmp_path / "full"
    full.mkdir()
    (full / erasures.LOG_NAME).write_text('{"id": "x", "sta\n{"id": "y"}\n')
    err = _refused(capsys, archive, full, "--force")
    assert "line 1: not an erasure log entry" in err
    assert sorted(p.name for p in full.iterdir()) == [erasures.LOG_NAME]


def test_restored_files_are_synced_before_they_are_moved_into_place(
        server: TestClient, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """A restore that reports success must survive a power cut right after it: every
    file and folder it wrote reaches the disk (fsync) before the data folder names it."""
    var = tmp_path / "var"
    p = server.post("/api/projects", json={"name": "Study"}).json()
    _subject(server, var, tmp_path, p["id"], KEEP, "R20260101-100000-aaaa")
    archive = bk.create_backup(var, tmp_path / "b.tar").path
    synced: list[str] = []
    real = bk.os.fsync

    def spy(fd: int) -> None:
        synced.append(bk.os.readlink(f"/proc/self/fd/{fd}"))
        real(fd)

    monkeypatch.setattr(bk.os, "fsync", spy)
    fresh = tmp_path / "fresh"
    code, _o, err = _cli(capsys, "restore", str(archive), "--data-dir", str(fresh),
                         "--without-deletion-log")
    monkeypatch.undo()
    assert code == 0, err

    def rel(path: str) -> str | None:
        q = Path(path)
        if q.is_relative_to(fresh):
            return str(q.relative_to(fresh))
        stage = [x for x in q.relative_to(tmp_path).parts if x.startswith(".fresh.restoring-")]
        return str(q.relative_to(tmp_path / stage[0])) if stage else None

    done = {rel(x) for x in synced}
    wrote = {str(q.relative_to(fresh)) for q in fresh.rglob("*")
             if q.name not in ("gaitrig.sqlite3-wal", "gaitrig.sqlite3-shm")} | {"."}
    assert wrote - done == set()


def test_the_archive_s_name_is_synced_too(server: TestClient, tmp_path: Path,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """The archive was synced, its rename into place not: a power cut after 'done' (and
    after a cron job pruned the older backups) could leave no archive at all."""
    synced: list[str] = []
    real = bk.os.fsync

    def spy(fd: int) -> None:
        synced.append(bk.os.readlink(f"/proc/self/fd/{fd}"))
        real(fd)

    monkeypatch.setattr(bk.os, "fsync", spy)
    dest = tmp_path / "backups"
    dest.mkdir()
    bk.create_backup(tmp_path / "var", dest / "b.tar")
    assert str(dest) in synced


def test_a_server_started_during_a_forced_restore_stops_the_swap(
        archive: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The database was checked for other users only before the (long) unpacking: a
    server started meanwhile had its folder replaced under it."""
    full = tmp_path / "full"
    code, _o, err = _cli(capsys, "restore", str(archive), "--data-dir", str(full),
                         "--without-deletion-log")
    assert code == 0, err
    before = sorted(p.name for p in full.iterdir())
    holders: list[subprocess.Popen[str]] = []
    real = bk._check_integrity

    def and_a_server_starts(db: Path, archive: Path) -> None:
        real(db, archive)
        h = subprocess.Popen(
            [sys.executable, "-c", "import sqlite3, sys; c = sqlite3.connect(sys.argv[1]); "
             "c.execute('pragma journal_mode=WAL'); c.execute('select 1').fetchall(); "
             "print('open', flush=True); sys.stdin.read()", str(full / "gaitrig.sqlite3")],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        holders.append(h)
        assert h.stdout is not None and h.stdout.readline().strip() == "open"

    monkeypatch.setattr(bk, "_check_integrity", and_a_server_starts)
    try:
        err = _refused(capsys, archive, full, "--force")
    finally:
        for h in holders:
            h.communicate("", timeout=10)
    assert holders and "opened by another program" in err
    assert sorted(p.name for p in full.iterdir()) == before


def test_force_refuses_an_archive_inside_the_folder_it_replaces(
        server: TestClient, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--force replaces everything in the folder: an archive kept there (a copy brought
    back from the NAS into the data folder) was deleted with it."""
    var = tmp_path / "var"
    full = tmp_path / "full"
    full.mkdir()
    archive = bk.create_backup(var, full / "b.tar").path
    assert "inside the folder" in _refused(capsys, archive, full, "--force")
    assert archive.is_file()


def test_the_erasure_log_s_recording_hash_is_described_as_what_it_is() -> None:
    """The log's recording hash was called "keyed"; it has no key: an id is found from its
    hash by trying the 65 536 ids of its start second. The docs say so."""
    rid = "R20260101-110000-b7e2"
    key = erasures.rec_key(rid)
    found = [c for c in (f"R20260101-110000-{k:04x}" for k in range(1 << 16))
             if erasures.rec_key(c) == key]
    assert found == [rid]
    root = Path(__file__).resolve().parents[2]
    for path in (root / "app/server/erasures.py", root / "docs/backup.md",
                 root / "docs/security.md"):
        text = " ".join(path.read_text().split()).lower()
        assert not re.search(r"(?<!un)keyed (sha|hash)", text), path
        assert "no secret key" in text or "unkeyed" in text, path


def test_a_postgresql_data_folder_without_a_log_says_what_to_do(
        archive: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--deletion-log took a SQLite data folder without a log as 'nothing deleted' but a
    PostgreSQL server's (no gaitrig.sqlite3) only as 'holds no erasures.jsonl'."""
    pg = tmp_path / "pg-var"
    (pg / "recordings").mkdir(parents=True)
    (pg / "calibrations").mkdir()
    code, _o, err = _cli(capsys, "restore", str(archive), "--data-dir",
                         str(tmp_path / "r"), "--deletion-log", str(pg))
    assert code == 2 and err.count("\n") == 1, err
    assert "looks like the data folder of a server using PostgreSQL" in err
    assert "--without-deletion-log" in err and "GAITRIG_DATA_DIR" in err
    assert not (tmp_path / "r").exists()
    other = tmp_path / "somewhere"
    other.mkdir()
    code, _o, err = _cli(capsys, "restore", str(archive), "--data-dir",
                         str(tmp_path / "r"), "--deletion-log", str(other))
    assert code == 2 and "is not a server's data folder" in err, err
    assert "PostgreSQL" in err and "--without-deletion-log" in err
    # the folder of a PostgreSQL server that did delete: its log is read
    erasures.begin(pg, [], None, {}, [("R20260101-100000-aaaa", "")])
    code, out, err = _cli(capsys, "restore", str(archive), "--data-dir",
                          str(tmp_path / "r"), "--deletion-log", str(pg))
    assert code == 0 and "(1 deletion of the erasure logs applied)" in out, err


def test_backup_and_restore_print_an_os_error_with_its_file(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from app.commands.backup import fail

    for command in ("backup", "restore"):
        exc = OSError(28, "No space left on device", str(tmp_path / "x.tar"))
        assert fail(command, exc, tmp_path) == 2
        assert capsys.readouterr().err == (
            f"gaitrig {command}: error: {tmp_path / 'x.tar'}: No space left on device\n")
        assert fail(command, bk.BackupError("say what to do"), tmp_path) == 2
        assert capsys.readouterr().err == f"gaitrig {command}: error: say what to do\n"
    assert fail("backup", OSError("no file named"), tmp_path / "b") == 2
    assert capsys.readouterr().err == f"gaitrig backup: error: {tmp_path / 'b'}: no file named\n"
