"""What the console's account pages read from the API: whether a password is still one
someone else chose (the generated first-run password, an administrator's temporary one),
cleared by the owner's own change, and each account's last login."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.config import Settings
from app.db.base import Base, alembic_head, make_engine
from app.db.models import ACCOUNT_TABLES
from app.main import create_app


def _settings(tmp_path: Path, admin_password: str | None) -> Settings:
    return Settings(data_dir=tmp_path, viewer_enabled=False, admin_password=admin_password,
                    node_token="accounts-node-token-1", calibration_check_interval_s=0)


def _bearer(client: TestClient, username: str, password: str) -> dict[str, str]:
    r = client.post("/api/auth/login", json={"username": username, "password": password})
    assert r.status_code == 200, r.text
    client.cookies.clear()  # each caller is its own browser: only its bearer token counts
    return {"Authorization": f"Bearer {r.json()['token']}"}


def _me(client: TestClient, who: dict[str, str]) -> Any:
    r = client.get("/api/auth/me", headers=who)
    assert r.status_code == 200, r.text
    return r.json()


def _accounts(client: TestClient, admin: dict[str, str]) -> dict[str, Any]:
    r = client.get("/api/users", headers=admin)
    assert r.status_code == 200, r.text
    return {u["username"]: u for u in r.json()}


def test_generated_password_is_flagged_until_its_owner_changes_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with TestClient(create_app(_settings(tmp_path, None)),
                    raise_server_exceptions=False) as client:
        printed = re.search(r"account 'admin' with password '([^']+)'", capsys.readouterr().err)
        assert printed, "the first start prints the generated password"
        password = printed.group(1)
        admin = _bearer(client, "admin", password)
        assert _me(client, admin) == {"username": "admin", "is_admin": True,
                                      "must_change_password": True,
                                      "password_set_by": "generated"}
        # a refused change (wrong current, too short) leaves the flag
        for body in ({"current_password": "not the one", "new_password": "tall green tripods 4"},
                     {"current_password": password, "new_password": "short"}):
            assert client.post("/api/auth/password", headers=admin, json=body).status_code in (
                403, 422)
            assert _me(client, admin)["must_change_password"]
        r = client.post("/api/auth/password", headers=admin,
                        json={"current_password": password,
                              "new_password": "tall green tripods 4"})
        # 200 with how many other logins ended (none: this client has only this one)
        assert r.status_code == 200 and r.json() == {"other_sessions_ended": 0}, r.text
        me = _me(client, admin)
        assert not me["must_change_password"] and me["password_set_by"] is None
        listed = _accounts(client, admin)["admin"]
        assert not listed["must_change_password"]
        assert listed["last_login_at"] is not None and listed["created_at"].endswith("+00:00")


def test_given_password_is_not_flagged(tmp_path: Path) -> None:
    with TestClient(create_app(_settings(tmp_path, "chosen by the operator 1")),
                    raise_server_exceptions=False) as client:
        admin = _bearer(client, "admin", "chosen by the operator 1")
        assert not _me(client, admin)["must_change_password"]


def test_temporary_passwords_of_administrators_and_last_login(tmp_path: Path) -> None:
    with TestClient(create_app(_settings(tmp_path, "chosen by the operator 1")),
                    raise_server_exceptions=False) as client:
        admin = _bearer(client, "admin", "chosen by the operator 1")
        r = client.post("/api/users", headers=admin,
                        json={"username": "a.nurse", "password": "temporary walk 11"})
        assert r.status_code == 201, r.text
        listed = _accounts(client, admin)["a.nurse"]
        assert listed["must_change_password"] and listed["password_set_by"] == "administrator"
        assert listed["last_login_at"] is None  # never logged in
        nurse = _bearer(client, "a.nurse", "temporary walk 11")
        assert _me(client, nurse)["password_set_by"] == "administrator"
        assert _accounts(client, admin)["a.nurse"]["last_login_at"] is not None
        r = client.post("/api/auth/password", headers=nurse,
                        json={"current_password": "temporary walk 11",
                              "new_password": "my own long walk 7"})
        assert r.status_code == 200 and r.json() == {"other_sessions_ended": 0}, r.text
        assert not _accounts(client, admin)["a.nurse"]["must_change_password"]
        # a reset by the administrator is a temporary password again
        r = client.post("/api/users/a.nurse/password", headers=admin,
                        json={"new_password": "reset by admin 22"})
        assert r.status_code == 204, r.text
        assert _accounts(client, admin)["a.nurse"]["password_set_by"] == "administrator"
        # removed and made again under the same name: the old account's logins and flag
        # are not the new one's
        r = client.post("/api/users/a.nurse/delete", headers=admin, json={"confirm": "a.nurse"})
        assert r.status_code == 200, r.text
        with sa.create_engine(f"sqlite:///{tmp_path / 'gaitrig.sqlite3'}").connect() as c:
            assert c.execute(sa.text("select count(*) from password_change_due")).scalar() == 0
        r = client.post("/api/users", headers=admin,
                        json={"username": "a.nurse", "password": "second nurse 333"})
        assert r.status_code == 201, r.text
        again = _accounts(client, admin)["a.nurse"]
        assert again["last_login_at"] is None and again["must_change_password"]


def _schema(path: Path) -> dict[str, Any]:
    """Columns (name, type, nullable, primary key), indexes and foreign keys of the
    account tables of a SQLite database."""
    with sa.create_engine(f"sqlite:///{path}").connect() as c:
        insp = sa.inspect(c)
        return {t: ([(col["name"], str(col["type"]), col["nullable"], col["primary_key"])
                     for col in insp.get_columns(t)],
                    sorted((i["name"], tuple(i["column_names"]), bool(i["unique"]))
                           for i in insp.get_indexes(t)),
                    [(f["referred_table"], f["constrained_columns"],
                      f["options"].get("ondelete")) for f in insp.get_foreign_keys(t)])
                for t in ACCOUNT_TABLES}


def _revision(path: Path) -> str:
    with sa.create_engine(f"sqlite:///{path}").connect() as c:
        return str(c.execute(sa.text("select version_num from alembic_version")).scalar())


def _upgrade(path: Path, revision: str) -> None:
    from alembic.config import Config

    from alembic import command
    from app.db.data import ALEMBIC_DIR

    cfg = Config()
    cfg.set_main_option("script_location", str(ALEMBIC_DIR))
    eng = sa.create_engine(f"sqlite:///{path}")
    with eng.begin() as conn:
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, revision)
    eng.dispose()


def test_one_alembic_head_and_it_owns_the_account_tables() -> None:
    """Revisions written in parallel must chain into one line; 0005 is on it."""
    from alembic.config import Config
    from alembic.script import ScriptDirectory

    from app.db.data import ALEMBIC_DIR

    cfg = Config()
    cfg.set_main_option("script_location", str(ALEMBIC_DIR))
    script = ScriptDirectory.from_config(cfg)
    assert len(script.get_heads()) == 1, script.get_heads()
    assert "0005" in {r.revision for r in script.walk_revisions()}
    assert alembic_head() == script.get_current_head()


def test_fresh_database_gets_the_account_tables_from_alembic(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A new database: the account tables come from revision 0005 (create_all is not
    asked for them) with the schema the models describe."""
    asked: list[str] = []
    real = sa.MetaData.create_all

    def spy(self: sa.MetaData, bind: Any, tables: Any = None, **kw: Any) -> None:
        asked.extend(t.name for t in (tables if tables is not None else self.sorted_tables))
        real(self, bind, tables=tables, **kw)

    monkeypatch.setattr(sa.MetaData, "create_all", spy)
    make_engine(tmp_path / "new.sqlite3").dispose()
    assert asked and not set(asked) & set(ACCOUNT_TABLES), asked
    assert _revision(tmp_path / "new.sqlite3") == alembic_head()
    monkeypatch.setattr(sa.MetaData, "create_all", real)
    # the same tables as the models' create_all made for earlier releases
    by_models = sa.create_engine(f"sqlite:///{tmp_path / 'models.sqlite3'}")
    Base.metadata.create_all(by_models, tables=[Base.metadata.tables[t] for t in ACCOUNT_TABLES])
    by_models.dispose()
    assert _schema(tmp_path / "new.sqlite3") == _schema(tmp_path / "models.sqlite3")
    # and the server works on it: the first start makes the administrator
    with TestClient(create_app(_settings(tmp_path, "chosen by the operator 1"))) as client:
        assert _me(client, _bearer(client, "admin", "chosen by the operator 1"))["is_admin"]


def test_existing_database_whose_account_tables_create_all_made_is_adopted(
        tmp_path: Path) -> None:
    """A database of a release before 0005 (data tables at 0003, the account tables and
    their rows made by create_all) keeps its accounts, logins and flags."""
    with TestClient(create_app(_settings(tmp_path, "chosen by the operator 1"))) as client:
        admin = _bearer(client, "admin", "chosen by the operator 1")
        r = client.post("/api/users", headers=admin,
                        json={"username": "a.nurse", "password": "temporary walk 11"})
        assert r.status_code == 201, r.text
    db = tmp_path / "gaitrig.sqlite3"
    before = _schema(db)
    with sa.create_engine(f"sqlite:///{db}").begin() as c:  # as the older release left it
        c.execute(sa.text("update alembic_version set version_num = '0003'"))
    with TestClient(create_app(_settings(tmp_path, "chosen by the operator 1")),
                    raise_server_exceptions=False) as client:
        assert _me(client, admin)["username"] == "admin"  # the login survived
        listed = _accounts(client, admin)
        assert set(listed) == {"admin", "a.nurse"} and listed["a.nurse"]["must_change_password"]
        assert _bearer(client, "a.nurse", "temporary walk 11")
    assert _revision(db) == alembic_head()
    assert _schema(db) == before


def test_database_of_an_older_release_gets_the_missing_table(tmp_path: Path) -> None:
    """A database from before ``password_change_due`` (at revision 0003, ``users`` made
    by create_all) gets it from 0005 at the next start, and its accounts are not flagged."""
    with TestClient(create_app(_settings(tmp_path, "chosen by the operator 1"))):
        pass
    db = tmp_path / "gaitrig.sqlite3"
    with sa.create_engine(f"sqlite:///{db}").begin() as c:
        c.execute(sa.text("drop table password_change_due"))
        c.execute(sa.text("update alembic_version set version_num = '0003'"))
    with TestClient(create_app(_settings(tmp_path, "chosen by the operator 1")),
                    raise_server_exceptions=False) as client:
        admin = _bearer(client, "admin", "chosen by the operator 1")
        assert not _me(client, admin)["must_change_password"]
        assert not _accounts(client, admin)["admin"]["must_change_password"]
    assert "password_change_due" in sa.inspect(sa.create_engine(f"sqlite:///{db}")
                                               ).get_table_names()
    assert _revision(db) == alembic_head()


def test_upgrade_from_0003_on_an_empty_database_and_downgrade_keeps_accounts(
        tmp_path: Path) -> None:
    """alembic alone (as ``alembic upgrade head`` on the command line) creates the account
    tables; a downgrade to 0003 keeps them (the older release uses them as they are)."""
    db = tmp_path / "cli.sqlite3"
    _upgrade(db, "0003")
    assert not set(ACCOUNT_TABLES) & set(
        sa.inspect(sa.create_engine(f"sqlite:///{db}")).get_table_names())
    _upgrade(db, "head")
    with sa.create_engine(f"sqlite:///{db}").begin() as c:
        c.execute(sa.text("insert into users (username, password_hash, is_admin, created_at) "
                          "values ('kept', 'x', 1, '2026-01-01 00:00:00')"))
    from alembic.config import Config

    from alembic import command
    from app.db.data import ALEMBIC_DIR

    cfg = Config()
    cfg.set_main_option("script_location", str(ALEMBIC_DIR))
    eng = sa.create_engine(f"sqlite:///{db}")
    with eng.begin() as conn:
        cfg.attributes["connection"] = conn
        command.downgrade(cfg, "0003")
    with eng.connect() as c:
        assert c.execute(sa.text("select username from users")).scalar() == "kept"
    eng.dispose()


def _timestamps(doc: Any, key: str = "") -> list[str]:
    """Every value under a key named ``at`` or ``*_at`` in a JSON document."""
    if isinstance(doc, dict):
        return [v for k, x in doc.items() for v in _timestamps(x, k)]
    if isinstance(doc, list):
        return [v for x in doc for v in _timestamps(x, key)]
    return [doc] if (key == "at" or key.endswith("_at")) and doc is not None else []


def test_every_timestamp_carries_its_offset_and_old_naive_values_read_as_utc(
        tmp_path: Path) -> None:
    """Rows stored without a zone (SQLite; an older release) come out as ISO 8601 with
    ``+00:00`` — in the JSON of audit, accounts, projects, subjects, sessions, recordings
    and references, and in the audit CSV — and mean the UTC time stored."""
    from datetime import UTC, datetime

    with TestClient(create_app(_settings(tmp_path, "chosen by the operator 1")),
                    raise_server_exceptions=False) as client:
        admin = _bearer(client, "admin", "chosen by the operator 1")
        naive = "2026-01-02 03:04:05.000000"  # how SQLite holds a UTC time
        with sa.create_engine(f"sqlite:///{tmp_path / 'gaitrig.sqlite3'}").begin() as c:
            c.execute(sa.text("insert into projects (id, name, description, created_at) "
                              f"values (77, 'old study', '', '{naive}')"))
            c.execute(sa.text("insert into subjects (id, project_id, code, sex, notes, "
                              f"created_at) values (78, 77, 'S-OLD', 'unknown', '', '{naive}')"))
            c.execute(sa.text("insert into sessions (id, subject_id, date, label, notes, "
                              f"created_at) values (79, 78, '2026-01-02', '', '', '{naive}')"))
            c.execute(sa.text("insert into recordings (id, session_id, label, notes, state, "
                              "streams, created_at) values ('R20260102-030405-ab12', 79, '', "
                              f"'', 'complete', 'skeleton', '{naive}')"))
            c.execute(sa.text("insert into audit_events (at, username, action, target, "
                              f"detail, client) values ('{naive}', 'old', 'export', 'x', '', '')"))
        docs = {path: client.get(path, headers=admin)
                for path in ("/api/audit", "/api/users", "/api/projects", "/api/subjects/78",
                             "/api/sessions/79", "/api/recordings?limit=50", "/api/system")}
        seen: list[str] = []
        for path, r in docs.items():
            assert r.status_code == 200, (path, r.text)
            got = _timestamps(r.json())
            assert all(isinstance(t, str) and t.endswith("+00:00") for t in got), (path, got)
            seen += got
        for path in ("/api/audit", "/api/projects", "/api/subjects/78"):
            assert "2026-01-02T03:04:05+00:00" in _timestamps(docs[path].json()), path
        assert {datetime.fromisoformat(t).tzinfo for t in seen} == {UTC}
        r = client.get("/api/audit", params={"format": "csv"}, headers=admin)
        assert r.status_code == 200, r.text
        rows = r.text.splitlines()
        assert rows[0].split(",")[:2] == ["id", "at"]
        ats = [line.split(",")[1] for line in rows[1:]]
        assert ats and all(a.endswith("+00:00") for a in ats), ats
        assert "2026-01-02T03:04:05+00:00" in ats
        # the login's expiry says its zone too
        r = client.post("/api/auth/login", json={"username": "admin",
                                                 "password": "chosen by the operator 1"})
        assert datetime.fromisoformat(r.json()["expires_at"]).utcoffset() is not None
