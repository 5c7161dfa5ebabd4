"""Live and planning routes in-process (no nodes): login required, clear 4xx errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from app.config import Settings
from app.main import create_app


@pytest.fixture
def client(tmp_path: Path) -> TestClient:
    app = create_app(Settings(data_dir=tmp_path, viewer_enabled=False,
                              admin_password="correct-horse-1"))
    with TestClient(app) as c:
        yield c


def test_live_socket_needs_the_session_cookie(client: TestClient) -> None:
    with pytest.raises(WebSocketDisconnect) as refused, \
            client.websocket_connect("/api/live/ws") as ws:
        ws.receive_text()
    assert refused.value.code == 4401
    client.cookies.set("gaitrig_session", "forged")
    with pytest.raises(WebSocketDisconnect), client.websocket_connect("/api/live/ws") as ws:
        ws.receive_text()
    client.cookies.clear()
    assert client.post("/api/auth/login", json={"username": "admin",
                                                "password": "correct-horse-1"}).status_code == 200
    with client.websocket_connect("/api/live/ws") as ws:
        hello = json.loads(ws.receive_text())
        assert hello["type"] == "hello" and hello["fps"] > 0
        ws.send_text(json.dumps({"type": "time", "echo": 12.5}))
        pong = json.loads(ws.receive_text())
        assert pong["echo"] == 12.5 and pong["t"] >= hello["t"]
        ws.send_text("not json")  # ignored, the stream stays open
        ws.send_text(json.dumps({"type": "time", "echo": 1}))
        assert json.loads(ws.receive_text())["echo"] == 1
        assert client.get("/api/live/status").json()["watchers"] == 1


def test_routes_require_login_and_explain_bad_input(client: TestClient) -> None:
    for path in ("/api/live/status", "/api/planning", "/api/planning/coverage.png",
                 "/api/planning/sheet"):
        assert client.get(path).status_code == 401, path
    client.post("/api/auth/login", json={"username": "admin", "password": "correct-horse-1"})
    r = client.get("/api/planning")
    assert r.status_code == 400 and "no sensor has a known pose" in r.json()["detail"]
    r = client.post("/api/planning/save", json={"name": "../../etc/x"})
    assert r.status_code == 422 and "name" in r.json()["detail"]
    r = client.put("/api/planning/sensors/S1", json={"pitch_deg": 120})
    assert r.status_code == 422
