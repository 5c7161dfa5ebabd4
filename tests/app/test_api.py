"""REST API, auth and the node websocket, in-process with a scripted node."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from app.nodes.protocol import Hello, Pong, Status, dump, encode_binary, encode_skeletons

TOKEN = "test-node-token-123"


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    return Settings(data_dir=tmp_path, viewer_enabled=False, node_token=TOKEN,
                    admin_password="secret-pw", max_control_bytes=4096,
                    max_binary_bytes=200_000, clock_ping_interval_s=0.02)


@pytest.fixture
def client(settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(settings)) as c:
        yield c


def _login(client: TestClient) -> dict[str, str]:
    r = client.post("/api/auth/login", json={"username": "admin", "password": "secret-pw"})
    assert r.status_code == 200, r.text
    return {"Authorization": f"Bearer {r.json()['token']}"}


def _recv_until(ws: Any, type_: str, answer_pings: bool = True,
                offset: float = 0.0) -> dict[str, Any]:
    while True:
        m = json.loads(ws.receive_text())
        if m["type"] == "ping" and answer_pings:
            t = time.time() + offset
            ws.send_text(dump(Pong(seq=m["seq"], t1=m["t1"], t2=t, t3=t)))
            if type_ == "ping":
                return m
            continue
        if m["type"] == type_:
            return m


def test_every_api_route_needs_login(client: TestClient) -> None:
    for path in ("/api/nodes", "/api/recordings", "/api/system", "/api/auth/me"):
        r = client.get(path)
        assert r.status_code == 401, path
        assert "log" in r.json()["detail"]
    assert client.post("/api/recordings", json={}).status_code == 401
    # every route under /api, present and future, except logging in and asking whether
    # anyone is logged in (which tells nobody anything but "no"). The OpenAPI schema
    # lists routes of nested routers too (app.routes does not flatten them).
    assert client.get("/api/auth/session").json() == {"logged_in": False, "user": None}
    paths = client.get("/openapi.json").json()["paths"]
    checked = 0
    for route_path, methods in paths.items():
        if not route_path.startswith("/api/") or route_path in ("/api/auth/login",
                                                                "/api/auth/session"):
            continue
        path = route_path.replace("{", "").replace("}", "")  # any value for path parameters
        for method in methods:
            r = client.request(method.upper(), path, json={})
            assert r.status_code == 401, f"{method.upper()} {route_path} answers {r.status_code}"
            checked += 1
    assert checked >= 20, f"only {checked} API routes found: route discovery is broken"
    assert client.get("/openapi.json").status_code == 200
    assert client.get("/docs").status_code == 200


def test_login_logout_and_cookie(client: TestClient) -> None:
    bad = client.post("/api/auth/login", json={"username": "admin", "password": "nope"})
    assert bad.status_code == 401
    r = client.post("/api/auth/login", json={"username": "admin", "password": "secret-pw"})
    assert r.status_code == 200 and "gaitrig_session" in r.cookies
    me = {"username": "admin", "is_admin": True, "must_change_password": False,
          "password_set_by": None}
    assert client.get("/api/auth/me").json() == me
    assert client.get("/api/auth/session").json() == {"logged_in": True, "user": me}
    assert client.post("/api/auth/logout").status_code == 204
    client.cookies.clear()
    h = {"Authorization": f"Bearer {r.json()['token']}"}
    assert client.get("/api/auth/me", headers=h).status_code == 401
    assert client.get("/api/auth/session", headers=h).json()["logged_in"] is False


def test_repeated_wrong_passwords_pause_that_user_on_that_address(client: TestClient) -> None:
    """Five wrong passwords: the sixth try, even the right one, is told to wait (429 with
    Retry-After and a message saying what to do); other users are not affected."""
    for _ in range(5):
        r = client.post("/api/auth/login", json={"username": "Admin", "password": "guess"})
        assert r.status_code == 401
    r = client.post("/api/auth/login", json={"username": "admin", "password": "secret-pw"})
    assert r.status_code == 429
    assert "try again in 5 min" in r.json()["detail"]
    assert 290 <= int(r.headers["Retry-After"]) <= 301
    other = client.post("/api/auth/login", json={"username": "nurse", "password": "x"})
    assert other.status_code == 401  # another name is still only refused


def test_login_throttle_window_and_reset() -> None:
    from app.api.security import LoginThrottle

    th = LoginThrottle(max_failures=3, window_s=60.0)
    for k in range(3):
        assert th.retry_after("a", "10.0.0.1", now=100.0 + k) == 0.0
        th.failed("a", "10.0.0.1", now=100.0 + k)
    assert th.retry_after("a", "10.0.0.1", now=103.0) == pytest.approx(57.0)
    assert th.retry_after("a", "10.0.0.2", now=103.0) == 0.0  # another address
    assert th.retry_after("a", "10.0.0.1", now=160.5) == 0.0  # the first failure aged out
    th.failed("a", "10.0.0.1", now=130.0)  # 101, 102, 130: three within the window again
    assert th.retry_after("a", "10.0.0.1", now=130.0) == pytest.approx(31.0)
    th.succeeded("A", "10.0.0.1")  # a good login clears the count (names are case-blind)
    assert th.retry_after("a", "10.0.0.1", now=130.0) == 0.0


def test_system_says_whether_nodes_pair_with_the_shipped_token(tmp_path: Path) -> None:
    from app.config import DEFAULT_NODE_TOKEN

    for token, expect in ((DEFAULT_NODE_TOKEN, True), (TOKEN, False)):
        s = Settings(data_dir=tmp_path / str(expect), viewer_enabled=False, node_token=token,
                     admin_password="secret-pw")
        with TestClient(create_app(s)) as c:
            assert c.get("/api/system", headers=_login(c)).json()["node_token_is_default"] is expect


def test_validation_errors_name_the_field_not_its_place_in_the_request(client: TestClient
                                                                         ) -> None:
    h = _login(client)
    r = client.post("/api/auth/login", json={"username": "admin"})
    assert r.status_code == 422 and r.json()["detail"] == "password: Field required"
    r = client.post("/api/auth/login", content=b"{", headers={"Content-Type": "application/json"})
    assert r.status_code == 422 and r.json()["detail"].startswith("the request body: "), r.text
    r = client.get("/api/subjects/abc", headers=h)
    assert r.status_code == 422 and r.json()["detail"].startswith("sid: "), r.text


def test_password_is_stored_hashed(client: TestClient, settings: Settings) -> None:
    import sqlite3

    row = sqlite3.connect(settings.db_path).execute("select password_hash from users").fetchone()
    assert row[0].startswith("scrypt$") and "secret-pw" not in row[0]


def test_wrong_token_refused(client: TestClient) -> None:
    with client.websocket_connect("/ws/node") as ws:
        ws.send_text(dump(Hello(node_id="S1", token="wrong-token")))
        m = json.loads(ws.receive_text())
        assert m["type"] == "refused" and "wrong pairing token" in m["reason"]
    assert client.get("/api/nodes", headers=_login(client)).json() == []


def test_node_health_malformed_messages_and_recording(client: TestClient) -> None:
    h = _login(client)
    offset = 0.25  # the scripted node's clock runs 250 ms ahead of the server's
    with client.websocket_connect("/ws/node") as ws:
        ws.send_text(dump(Hello(node_id="S1", token=TOKEN, agent_started=1.0)))
        assert json.loads(ws.receive_text())["type"] == "welcome"
        for k in range(40):
            _recv_until(ws, "ping", offset=offset)
            t = time.time() + offset
            ws.send_bytes(encode_skeletons(k + 1, t, np.zeros((1, 25, 3)), np.full((1, 25), 2)))
        ws.send_text(dump(Status(fps=30.0, frames=40, dropped=0, disk_free_bytes=10**12)))
        # malformed and oversized messages: an error back, and the link stays up
        ws.send_text("{not json")
        assert "not valid JSON" in _recv_until(ws, "error")["reason"]
        ws.send_text(json.dumps({"type": "error", "reason": "x" * 5000}))
        assert "exceeds" in _recv_until(ws, "error")["reason"]
        big = encode_binary({"kind": "image", "stream": "depth", "t": 0.0}, b"\0" * 300_000)
        ws.send_bytes(big)
        assert "exceeds" in _recv_until(ws, "error")["reason"]
        ws.send_bytes(b"GRB\x01garbage")
        assert "binary" in _recv_until(ws, "error")["reason"]
        _recv_until(ws, "ping", offset=offset)

        nodes = client.get("/api/nodes", headers=h).json()
        assert [n["id"] for n in nodes] == ["S1"]
        n = nodes[0]
        assert n["connected"] and n["frames"] == 40 and n["dropped_frames"] == 0
        assert n["rejected_messages"] == 4
        assert n["clock_offset_ms"] == pytest.approx(offset * 1e3, abs=5.0)
        assert n["clock_uncertainty_ms"] is not None

        r = client.post("/api/recordings", json={}, headers=h)
        assert r.status_code == 201, r.text
        rec = r.json()
        start = _recv_until(ws, "rec_start", offset=offset)
        assert start["rec_id"] == rec["id"]
        assert start["t_start_local"] - start["t_start_server"] == pytest.approx(offset, abs=5e-3)
        assert client.post("/api/recordings", json={}, headers=h).status_code == 409
        stopped = client.post(f"/api/recordings/{rec['id']}/stop", headers=h).json()
        stop = _recv_until(ws, "rec_stop", offset=offset)
        assert stop["t_stop_server"] == pytest.approx(stopped["t_stop"])
    # the node vanished before confirming: its part is incomplete, with the reason
    rec2 = client.get(f"/api/recordings/{rec['id']}", headers=h).json()
    assert rec2["state"] == "incomplete"
    assert "disconnected" in rec2["parts"][0]["reason"]
    node = client.get("/api/nodes/S1", headers=h).json()
    assert not node["connected"] and node["warnings"]


def test_skeleton_with_missing_joints_is_valid_json(client: TestClient) -> None:
    h = _login(client)
    pos = np.zeros((1, 25, 3), np.float32)
    pos[0, 3] = np.nan  # a joint without an estimate
    with client.websocket_connect("/ws/node") as ws:
        ws.send_text(dump(Hello(node_id="S4", token=TOKEN, agent_started=2.0)))
        assert json.loads(ws.receive_text())["type"] == "welcome"
        _recv_until(ws, "ping")
        ws.send_bytes(encode_skeletons(1, time.time(), pos, np.full((1, 25), 2)))
        _recv_until(ws, "ping")
        r = client.get("/api/nodes/S4/skeleton", headers=h)
    assert r.status_code == 200
    sk = r.json()
    assert sk["positions"][0][3] == [None, None, None] and sk["positions"][0][0] == [0, 0, 0]


def test_start_without_nodes_is_a_clear_409(client: TestClient) -> None:
    r = client.post("/api/recordings", json={}, headers=_login(client))
    assert r.status_code == 409 and "no connected node" in r.json()["detail"]
    r = client.get("/api/nodes/S9", headers=_login(client))
    assert r.status_code == 404 and "S9" in r.json()["detail"]


def test_console_pages_served(client: TestClient) -> None:
    assert client.get("/", follow_redirects=False).status_code in (302, 307)
    for page in ("/index.html", "/rig.html", "/console.js", "/style.css"):
        assert client.get(page).status_code == 200, page


def test_first_run_generates_and_prints_admin_password(tmp_path: Path,
                                                      capfd: pytest.CaptureFixture[str]) -> None:
    import re

    settings = Settings(data_dir=tmp_path, viewer_enabled=False, node_token=TOKEN)
    with TestClient(create_app(settings)) as c:
        out = capfd.readouterr().err
        m = re.search(r"created console account 'admin' with password '([^']+)'", out)
        assert m, out
        r = c.post("/api/auth/login", json={"username": "admin", "password": m.group(1)})
        assert r.status_code == 200
    with TestClient(create_app(settings)):  # second run: the account exists, nothing printed
        assert "created console account" not in capfd.readouterr().err
