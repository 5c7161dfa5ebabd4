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
        assert r.status_code == 204, r.text
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
        assert r.status_code == 204, r.text
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


def test_database_of_an_older_release_gets_the_table(tmp_path: Path) -> None:
    """``users`` is made by ``create_all``: a database from before this table gets it at
    the next start (no migration needed), and its accounts are not flagged."""
    with TestClient(create_app(_settings(tmp_path, "chosen by the operator 1"))):
        pass
    db = tmp_path / "gaitrig.sqlite3"
    with sa.create_engine(f"sqlite:///{db}").begin() as c:
        c.execute(sa.text("drop table password_change_due"))
    with TestClient(create_app(_settings(tmp_path, "chosen by the operator 1")),
                    raise_server_exceptions=False) as client:
        admin = _bearer(client, "admin", "chosen by the operator 1")
        assert not _me(client, admin)["must_change_password"]
        assert not _accounts(client, admin)["admin"]["must_change_password"]
