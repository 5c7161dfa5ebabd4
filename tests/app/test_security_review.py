"""The server as a health-data system: what a hospital's IT security review checks.

Cross-site requests (CSRF, cross-site websocket hijacking), security headers and caching,
cookie flags, session expiry and idle timeout, password changes and policy, login
throttling and its audit, node-websocket identities, production start-up refusals and
error answers without internals. ``docs/security.md`` describes the model tested here.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from app.config import Settings
from app.main import create_app

PASSWORD = "review-pw-12345"
BASE = "http://testserver"


def _settings(tmp_path: Path, **over: Any) -> Settings:
    kw: dict[str, Any] = dict(data_dir=tmp_path, viewer_enabled=False, admin_password=PASSWORD,
                              node_token="review-node-token-1", calibration_check_interval_s=0)
    kw.update(over)
    return Settings(**kw)


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    with TestClient(create_app(_settings(tmp_path)), raise_server_exceptions=False) as c:
        yield c


def _login(client: TestClient, password: str = PASSWORD) -> Any:
    r = client.post("/api/auth/login", json={"username": "admin", "password": password})
    assert r.status_code == 200, r.text
    return r


def _subject(client: TestClient, code: str = "SEC01") -> int:
    r = client.post("/api/projects", json={"name": f"review {code}"})
    assert r.status_code == 201, r.text
    r = client.post("/api/subjects", json={"project_id": r.json()["id"], "code": code})
    assert r.status_code == 201, r.text
    return int(r.json()["id"])


# ----------------------------------------------------------------------------- CSRF


def test_cross_site_form_post_cannot_delete_a_subject(client: TestClient) -> None:
    """A page on another origin (even another port of the same host, which SameSite
    does not stop) submitting a form or fetch with the console's cookie is refused."""
    _login(client)  # the cookie jar now holds the session cookie, as a browser would
    sid = _subject(client)
    url = f"/api/subjects/{sid}/delete"
    for origin in ("http://evil.example.org", "http://testserver:8081", "null",
                   "https://testserver.evil.org"):
        r = client.post(url, headers={"Origin": origin}, json={"confirm": "SEC01"})
        assert r.status_code == 403, (origin, r.text)
        assert "cross-site" in r.json()["detail"]
        # a plain HTML form (no pre-flight): refused before its body is even parsed
        r = client.post(url, headers={"Origin": origin}, data={"confirm": "SEC01"})
        assert r.status_code == 403, (origin, r.text)
    # no Origin, but a foreign Referer (an old browser): refused too
    r = client.post(url, headers={"Referer": "http://evil.example.org/x"},
                    json={"confirm": "SEC01"})
    assert r.status_code == 403
    assert client.get(f"/api/subjects/{sid}").status_code == 200  # still there
    # the console itself (same origin) can
    r = client.post(url, headers={"Origin": BASE}, json={"confirm": "SEC01"})
    assert r.status_code == 200, r.text
    assert client.get(f"/api/subjects/{sid}").status_code == 404


def test_same_origin_behind_a_proxy_and_listed_origins(tmp_path: Path) -> None:
    """Behind a TLS proxy the origin is https but the scheme the server sees is http; a
    proxy's X-Forwarded-Host counts as the server's own name; a listed origin is allowed."""
    s = _settings(tmp_path, allowed_origins=["https://gait.clinic.example.org"])
    with TestClient(create_app(s), raise_server_exceptions=False) as c:
        ok = [{"Origin": "https://testserver"},  # TLS terminated in front
              {"Origin": "https://lab.example.org", "X-Forwarded-Host": "lab.example.org"},
              {"Origin": "https://gait.clinic.example.org"}]
        for h in ok:
            r = c.post("/api/auth/login", json={"username": "admin", "password": PASSWORD},
                       headers=h)
            assert r.status_code == 200, (h, r.text)
        r = c.post("/api/auth/login", json={"username": "admin", "password": PASSWORD},
                   headers={"Origin": "https://other.clinic.example.org"})
        assert r.status_code == 403


def test_cross_site_websockets_are_refused(client: TestClient) -> None:
    """The live view's websocket authenticates by cookie: a foreign page must not open it
    (cross-site websocket hijacking); the console's own page may."""
    _login(client)
    with pytest.raises(WebSocketDisconnect) as e, client.websocket_connect(
            "/api/live/ws", headers={"Origin": "http://evil.example.org"}):
        pass
    assert e.value.code == 4403
    with client.websocket_connect("/api/live/ws", headers={"Origin": BASE}) as ws:
        ws.close()


# ---------------------------------------------------------------------------- headers


def test_security_headers_on_console_and_api(client: TestClient) -> None:
    page = client.get("/rig.html")
    assert page.status_code == 200
    csp = page.headers["content-security-policy"]
    assert "frame-ancestors 'self'" in csp and "object-src 'none'" in csp
    assert "'unsafe-inline'" not in csp.split("script-src")[1].split(";")[0]
    # the page's inline bootstrap script is allowed by its hash, and only it
    assert "'sha256-" in csp
    for h, v in {"x-content-type-options": "nosniff", "x-frame-options": "SAMEORIGIN",
                 "referrer-policy": "same-origin"}.items():
        assert page.headers[h] == v, h
    assert "strict-transport-security" not in page.headers  # plain http: no HSTS
    anon = client.get("/api/subjects")
    assert anon.status_code == 401 and anon.headers["cache-control"] == "no-store"
    _login(client)
    _subject(client)
    r = client.get("/api/subjects")
    assert r.status_code == 200
    assert r.headers["cache-control"] == "no-store"
    assert r.headers["x-content-type-options"] == "nosniff"
    # the 3D view's page has its own policy (viser unpacks an inline module, runs wasm)
    v = client.get("/viewer/", headers={"Accept": "text/html"})
    assert "'wasm-unsafe-eval'" in v.headers["content-security-policy"]
    assert "frame-ancestors 'self'" in v.headers["content-security-policy"]


def test_hsts_when_served_over_https(tmp_path: Path) -> None:
    with TestClient(create_app(_settings(tmp_path)), base_url="https://testserver") as c:
        assert c.get("/rig.html").headers["strict-transport-security"].startswith("max-age=")
