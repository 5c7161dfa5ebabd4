"""``gaitrig backup`` / ``restore`` with the database on PostgreSQL (a real, throw-away
server: ``pg_server`` in :mod:`tests.app.data.conftest`; skipped with the reason when
PostgreSQL or psycopg is absent), done as docs/backup.md tells the operator: ``pg_dump``
first, then ``gaitrig backup`` (the files), then, after the database is lost,
``pg_restore`` into an empty database and ``gaitrig restore`` of the files. Everything
comes back: the rows of every table, the files, the audit trail, the alembic revision;
a subject deleted after the backup stays deleted."""

from __future__ import annotations

import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.config import Settings
from app.db.base import alembic_head, make_engine
from app.main import create_app
from app.server import backup as bk
from tests.app.data.conftest import pg_tool
from tests.app.test_backup import GONE, KEEP, _cli, _files, _subject

_OPTS = dict(viewer_enabled=False, node_token="test-node-token", admin_password="secret-pw")


@pytest.fixture
def pg_env(pg_url: str, monkeypatch: pytest.MonkeyPatch) -> str:
    """``GAITRIG_DATABASE_URL`` set to a fresh database (as the operator's settings)."""
    monkeypatch.setenv("GAITRIG_DATABASE_URL", pg_url)
    return pg_url


def _client(data_dir: Path, url: str) -> TestClient:
    c = TestClient(create_app(Settings(data_dir=data_dir, database_url=url, **_OPTS)))
    c.__enter__()
    r = c.post("/api/auth/login", json={"username": "admin", "password": "secret-pw"})
    c.headers["Authorization"] = f"Bearer {r.json()['token']}"
    return c


@pytest.fixture
def pg_server_client(pg_env: str, tmp_path: Path) -> Iterator[TestClient]:
    c = _client(tmp_path / "var", pg_env)
    yield c
    c.__exit__(None, None, None)


def _libpq(url: str) -> str:
    """The URL as pg_dump/pg_restore take it (no SQLAlchemy driver part)."""
    return url.replace("postgresql+psycopg://", "postgresql://", 1)


def _tool(name: str) -> str:
    found = pg_tool(name)
    if found is None:
        pytest.skip(f"{name} is not installed (apt-get install postgresql-client)")
    return found


def _rows(url: str) -> dict[str, list[tuple[Any, ...]]]:
    """Every row of every table, in primary-key order (the sequences' next values too)."""
    eng = sa.create_engine(url)
    try:
        meta = sa.MetaData()
        meta.reflect(eng)
        out: dict[str, list[tuple[Any, ...]]] = {}
        with eng.connect() as c:
            for name, t in sorted(meta.tables.items()):
                order = list(t.primary_key.columns) or list(t.columns)
                out[name] = [tuple(r) for r in c.execute(sa.select(t).order_by(*order))]
            for (seq,) in c.execute(sa.text(
                    "select sequencename from pg_sequences order by 1")):
                out[f"sequence {seq}"] = [(c.execute(sa.text(
                    f'select last_value from "{seq}"')).scalar(),)]
    finally:
        eng.dispose()
    return out


def _recreate(pg_url: str) -> None:
    """Drop the database (its server lost) and create it again, empty."""
    name = sa.engine.make_url(pg_url).database
    admin = sa.create_engine(sa.engine.make_url(pg_url).set(database="postgres"),
                             isolation_level="AUTOCOMMIT")
    try:
        with admin.connect() as c:
            c.execute(sa.text(f'drop database "{name}" with (force)'))
            c.execute(sa.text(f'create database "{name}"'))
    finally:
        admin.dispose()


def test_backup_and_restore_on_postgresql(pg_server_client: TestClient, pg_env: str,
                                          tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    server, url, var = pg_server_client, pg_env, tmp_path / "var"
    pg_dump, pg_restore = _tool("pg_dump"), _tool("pg_restore")
    p = server.post("/api/projects", json={"name": "Study"}).json()
    _subject(server, var, tmp_path, p["id"], KEEP, "R20260101-100000-aaaa")
    gone = _subject(server, var, tmp_path, p["id"], GONE, "R20260101-110000-gone")
    assert server.get(f"/api/subjects/{gone['id']}").status_code == 200

    # the operator's backup: the database with pg_dump first, then the files
    dump = tmp_path / "backups" / "gaitrig.pgdump"
    dump.parent.mkdir()
    r = subprocess.run([pg_dump, "-Fc", "-f", str(dump), _libpq(url)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    at_dump = _rows(url)
    code, out, err = _cli(capsys, "backup", str(dump.parent), "--data-dir", str(var))
    assert code == 0, err
    archive = next(dump.parent.glob("gaitrig-backup-*.tar"))
    man = bk.verify_backup(archive).manifest
    assert man["database"]["member"] is None and man["database"]["dialect"] == "postgresql"
    assert "NOTE: the database is PostgreSQL" in out and "pg_dump" in out
    assert man["alembic_revision"] == alembic_head()  # of the database the files go with
    assert man["counts"]["subjects"] == 2 and man["counts"]["recordings"] == 2
    assert "2 subjects, 2 recordings" in out
    ev = server.get("/api/audit", params={"action": "backup"}).json()
    ev = ev.get("events", ev) if isinstance(ev, dict) else ev
    assert ev and ev[0]["target"] == archive.name  # recorded in the PostgreSQL database
    code, out, err = _cli(capsys, "backup", "--verify", str(archive))
    assert code == 0 and "every checksum matches (no database in it: PostgreSQL)" in out, err

    # after the backup the subject GONE is deleted: it must stay deleted
    r = server.post(f"/api/subjects/{gone['id']}/delete", json={"confirm": GONE})
    assert r.status_code == 200, r.text
    files = _files(var)
    server.__exit__(None, None, None)

    # the server is lost: its database dropped, its data folder gone (but for the
    # erasure log, kept as docs/backup.md asks: here the old folder moved aside)
    old = tmp_path / "old-var"
    var.rename(old)
    _recreate(url)
    # gaitrig restore before the database is restored refuses (it would migrate an empty
    # database and serve no subjects)
    code, _o, err = _cli(capsys, "restore", str(archive), "--data-dir", str(var),
                         "--deletion-log", str(old))
    assert code == 2 and "pg_restore" in err and "is empty" in err, err
    assert not var.exists()
    r = subprocess.run([pg_restore, "--no-owner", "--exit-on-error", "-d", _libpq(url),
                        str(dump)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert _rows(url) == at_dump
    # ... and while another program (a server started too early) uses the database
    other = sa.create_engine(url)
    with other.connect():
        code, _o, err = _cli(capsys, "restore", str(archive), "--data-dir", str(var),
                             "--deletion-log", str(old))
    other.dispose()
    assert code == 2 and "is in use" in err and "stop the server" in err, err
    assert not var.exists() and _rows(url) == at_dump
    code, out, err = _cli(capsys, "restore", str(archive), "--data-dir", str(var),
                          "--deletion-log", str(old))
    assert code == 0, err
    assert "rows differ" not in out
    assert f"database revision {alembic_head()} -> {alembic_head()}" in out
    assert "1 deleted recording kept deleted" in out

    # files: all back, byte for byte, but the deleted subject's
    assert _files(var) == files
    assert _files(var) == {k: v for k, v in _files_of(archive).items()
                           if "R20260101-110000-gone" not in k}
    # rows: as at the dump, less the deleted subject's, plus the restore's audit entry
    after = _rows(url)
    assert after["alembic_version"] == [(alembic_head(),)]
    assert [r[1] for r in after["subjects"]] == [r[1] for r in at_dump["subjects"]
                                                   if r[0] != gone["id"]]
    assert all(GONE not in str(row) for t, rows in after.items() if t != "audit_events"
               for row in rows)
    for t in ("projects", "users", "user_sessions"):
        if t in at_dump:
            assert after[t] == at_dump[t], t
    assert [r for r in at_dump["recordings"] if r[0] != "R20260101-110000-gone"] == \
        after["recordings"]
    audit = after["audit_events"]
    assert audit[:len(at_dump["audit_events"])] == at_dump["audit_events"]
    restore_ev = audit[len(at_dump["audit_events"]):]
    assert [r for r in restore_ev if "restore" in r] and len(restore_ev) == 1

    # the restored server serves the kept subject and its recording
    c = _client(var, url)
    try:
        subjects = c.get("/api/subjects").json()
        assert [s["code"] for s in subjects] == [KEEP]
        rec = c.get("/api/storage/recordings/R20260101-100000-aaaa").json()
        assert rec["state"] == "complete" and rec["bytes_on_server"] > 0
    finally:
        c.__exit__(None, None, None)
    shutil.rmtree(old)


def _files_of(archive: Path) -> dict[str, str]:
    """SHA-256 of the archive's recording and reference files (from its manifest)."""
    man = bk.verify_backup(archive).manifest
    return {e["name"][len(bk.FILES):]: e["sha256"] for e in man["members"]
            if e["name"].startswith((bk.FILES + "recordings/", bk.FILES + "references/"))}


def test_a_sqlite_backup_restored_with_a_postgresql_url_says_which_database_it_is(
        pg_env: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The archive's SQLite database is restored into the data folder; the PostgreSQL
    database of GAITRIG_DATABASE_URL is left alone, and the output says so."""
    var = tmp_path / "var"
    make_engine(var / "gaitrig.sqlite3").dispose()
    archive = bk.create_backup(var, tmp_path / "b.tar").path
    code, out, err = _cli(capsys, "restore", str(archive), "--data-dir",
                          str(tmp_path / "r"), "--without-deletion-log")
    assert code == 0, err
    assert "holds a SQLite database" in out and "unset GAITRIG_DATABASE_URL" in out
    assert (tmp_path / "r" / "gaitrig.sqlite3").is_file()
    assert _rows(pg_env) == {}  # nothing created there
