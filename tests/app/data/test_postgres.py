"""The database on PostgreSQL, "by changing the URL": the migrations and the data API run
against a real PostgreSQL server started by the test (a private unix socket, trust auth,
thrown away afterwards: ``pg_server``/``pg_url`` in :mod:`tests.app.data.conftest`).
Skipped, with the reason, when PostgreSQL (``initdb``/``pg_ctl``) or the ``psycopg``
driver is not installed."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.config import Settings
from app.db.base import alembic_head, make_engine
from app.main import create_app
from tests.app.data import test_data_api


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
