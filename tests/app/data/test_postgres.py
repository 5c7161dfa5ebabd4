"""The database on PostgreSQL, "by changing the URL": the migrations and the data API run
against a real PostgreSQL server started by the test (a private unix socket, trust auth,
thrown away afterwards). Skipped, with the reason, when PostgreSQL (``initdb``/``pg_ctl``)
or the ``psycopg`` driver is not installed."""

from __future__ import annotations

import glob
import itertools
import os
import pwd
import shutil
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.config import Settings
from app.db.base import alembic_head, make_engine
from app.main import create_app
from tests.app.data import test_data_api

_dbs = itertools.count(1)


def _pg_tool(name: str) -> str | None:
    found = shutil.which(name)
    if found:
        return found
    versions = sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"))
    return versions[-1] if versions else None


@pytest.fixture(scope="module")
def pg_server() -> Iterator[str]:
    """Base URL (without database) of a throw-away PostgreSQL server."""
    initdb, pg_ctl = _pg_tool("initdb"), _pg_tool("pg_ctl")
    if initdb is None or pg_ctl is None:
        pytest.skip("PostgreSQL is not installed (no initdb/pg_ctl; apt-get install postgresql)")
    pytest.importorskip("psycopg", reason="the psycopg driver is not installed "
                                          "(pip install 'psycopg[binary]')")
    prefix: list[str] = []
    root = Path(tempfile.mkdtemp(prefix="gaitrig-pg-"))
    if os.geteuid() == 0:  # PostgreSQL refuses to run as root
        try:
            user = pwd.getpwnam("postgres")
        except KeyError:
            shutil.rmtree(root)
            pytest.skip("running as root and there is no 'postgres' user to run PostgreSQL")
        os.chown(root, user.pw_uid, user.pw_gid)
        prefix = ["runuser", "-u", "postgres", "--"]
    data, sock = root / "data", root / "sock"

    def run(*cmd: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([*prefix, *cmd], capture_output=True, text=True, timeout=120)

    r = run("mkdir", str(sock))
    r = run(initdb, "-D", str(data), "-U", "gaitrig", "-A", "trust", "-E", "UTF8", "--no-sync")
    if r.returncode != 0:
        shutil.rmtree(root, ignore_errors=True)
        pytest.skip(f"initdb failed: {r.stderr.strip()[-300:]}")
    r = run(pg_ctl, "-D", str(data), "-l", str(root / "log"), "-w", "-o",
            f"-k {sock} -c listen_addresses='' -p 5432 -F", "start")
    if r.returncode != 0:
        log = (root / "log").read_text(errors="replace") if (root / "log").exists() else ""
        shutil.rmtree(root, ignore_errors=True)
        pytest.skip(f"PostgreSQL did not start: {(r.stderr + log).strip()[-300:]}")
    try:
        yield f"postgresql+psycopg://gaitrig@/{{db}}?host={sock}&port=5432"
    finally:
        run(pg_ctl, "-D", str(data), "-m", "immediate", "stop")
        shutil.rmtree(root, ignore_errors=True)


@pytest.fixture
def pg_url(pg_server: str) -> str:
    """A fresh, empty database on the server."""
    name = f"gaitrig_test_{next(_dbs)}"
    admin = sa.create_engine(pg_server.format(db="postgres"), isolation_level="AUTOCOMMIT")
    with admin.connect() as c:
        c.execute(sa.text(f"create database {name}"))
    admin.dispose()
    return pg_server.format(db=name)


@pytest.fixture
def pg_client(pg_url: str, tmp_path: Path) -> Iterator[TestClient]:
    s = Settings(data_dir=tmp_path, viewer_enabled=False, node_token="test-node-token",
                 admin_password="secret-pw", database_url=pg_url)
    with TestClient(create_app(s)) as c:
        r = c.post("/api/auth/login", json={"username": "admin", "password": "secret-pw"})
        c.headers["Authorization"] = f"Bearer {r.json()['token']}"
        yield c


def test_migrations_on_postgresql(pg_url: str) -> None:
    for _ in range(2):  # a new database, then one already at the newest revision
        eng = make_engine(pg_url)
        assert eng.dialect.name == "postgresql"
        with eng.connect() as c:
            version = c.execute(sa.text("select version_num from alembic_version")).scalar()
            assert version == alembic_head()
            tables = set(sa.inspect(c).get_table_names())
        eng.dispose()
    assert {"projects", "subjects", "sessions", "recordings", "recording_parts",
            "reference_imports"} <= tables


def test_data_api_on_postgresql(pg_client: TestClient, tmp_path: Path) -> None:
    """The same CRUD, validation, confirmation and export checks as on SQLite."""
    assert pg_client.app.state.db_sessions.kw["bind"].dialect.name == "postgresql"  # type: ignore[attr-defined]
    test_data_api.test_crud_validation_and_confirmation(pg_client)
    test_data_api.test_fused_export_keeps_the_recordings_own_poses(pg_client, tmp_path)


def test_audit_trail_and_deletion_on_postgresql(pg_client: TestClient, tmp_path: Path) -> None:
    """The audit trail (append-only there too) and a subject's deletion."""
    from tests.app.data import test_subject_data

    test_subject_data.test_audit_trail_of_logins_exports_and_deletions(pg_client, tmp_path)


def test_storage_usage_on_postgresql(pg_client: TestClient) -> None:
    """GET /api/storage joins each subject's recording ids in SQL (string aggregation,
    grouped by the subject's key): PostgreSQL must accept it as SQLite does."""
    from app.db import data as m

    c = pg_client
    pid = c.post("/api/projects", json={"name": "pg"}).json()["id"]
    a = c.post("/api/subjects", json={"project_id": pid, "code": "A1"}).json()["id"]
    c.post("/api/subjects", json={"project_id": pid, "code": "B2"})
    se = c.post("/api/sessions", json={"subject_id": a}).json()["id"]
    with c.app.state.db_sessions() as db:  # type: ignore[attr-defined]
        db.add_all([m.Recording(id="R1", session_id=se, state="complete"),
                    m.Recording(id="R2", session_id=se, state="complete")])
        db.commit()
    r = c.get("/api/storage")
    assert r.status_code == 200, r.text
    assert [(x["code"], x["n_recordings"], x["bytes"]) for x in r.json()["subjects"]] == [
        ("A1", 2, 0), ("B2", 0, 0)]
