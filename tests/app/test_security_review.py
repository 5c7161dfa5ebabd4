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
    assert "'unsafe-eval'" not in csp.split("script-src")[1].split(";")[0]
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


def test_a_forged_host_cannot_add_to_the_policy(client: TestClient) -> None:
    r = client.get("/rig.html", headers={"Host": "x; script-src *"})
    csp = r.headers["content-security-policy"]
    assert "script-src *" not in csp and "x;" not in csp
    r = client.get("/rig.html", headers={"Host": "lab.example.org:8443"})
    assert "wss://lab.example.org:8443" in r.headers["content-security-policy"]


def test_hsts_when_served_over_https(tmp_path: Path) -> None:
    with TestClient(create_app(_settings(tmp_path)), base_url="https://testserver") as c:
        assert c.get("/rig.html").headers["strict-transport-security"].startswith("max-age=")


# ---------------------------------------------------------------------------- sessions


def _set_cookie(r: Any) -> str:
    return "; ".join(v for k, v in r.headers.multi_items() if k.lower() == "set-cookie")


def test_session_cookie_flags(tmp_path: Path) -> None:
    """HttpOnly and SameSite=Strict always; Secure over HTTPS (directly or as a trusted
    proxy reports it) or when the operator says so."""
    with TestClient(create_app(_settings(tmp_path / "a"))) as c:
        cookie = _set_cookie(_login(c)).lower()
        assert "httponly" in cookie and "samesite=strict" in cookie
        assert "secure" not in cookie.replace("samesite", "")  # plain http on a workstation
    with TestClient(create_app(_settings(tmp_path / "b")), base_url="https://testserver") as c:
        assert "; secure" in _set_cookie(_login(c)).lower()
    with TestClient(create_app(_settings(tmp_path / "c", cookie_secure=True))) as c:
        assert "; secure" in _set_cookie(_login(c)).lower()


def test_logout_ends_the_login_on_the_server(client: TestClient) -> None:
    token = _login(client).json()["token"]
    bearer = {"Authorization": f"Bearer {token}"}
    assert client.get("/api/auth/me", headers=bearer).status_code == 200
    assert client.post("/api/auth/logout", headers=bearer).status_code == 204
    # a copy of the token (or of the cookie) is worthless afterwards
    assert client.get("/api/auth/me", headers=bearer).status_code == 401
    client.cookies.set("gaitrig_session", token)
    assert client.get("/api/auth/me").status_code == 401


def test_login_never_adopts_a_planted_session(client: TestClient) -> None:
    """Session fixation: a login mints a new token and sets it as the cookie; a token
    someone put into the browser before is not what the victim's login authenticates."""
    planted = _login(client).json()["token"]
    client.cookies.clear()
    client.cookies.set("gaitrig_session", "planted-by-someone-else")
    r = _login(client)
    assert r.json()["token"] not in (planted, "planted-by-someone-else")
    assert f"gaitrig_session={r.json()['token']}" in _set_cookie(r)


def _login_session(client: TestClient) -> Any:
    from sqlalchemy import select

    from app.db.models import LoginSession

    db = client.app.state.db_sessions()  # type: ignore[attr-defined]
    return db, db.scalars(select(LoginSession)).one()


def test_idle_timeout_and_absolute_lifetime(tmp_path: Path) -> None:
    from datetime import UTC, datetime, timedelta

    s = _settings(tmp_path, session_idle_minutes=30, session_hours=12)
    with TestClient(create_app(s)) as c:
        body = _login(c).json()
        left = datetime.fromisoformat(body["expires_at"]) - datetime.now(UTC)
        assert timedelta(minutes=29) < left <= timedelta(minutes=30)  # idle, not 12 h
        bearer = {"Authorization": f"Bearer {body['token']}"}
        c.cookies.clear()

        def expiry() -> datetime:
            db, sess = _login_session(c)
            with db:
                return sess.expires_at.replace(tzinfo=UTC)

        def set_times(expires: datetime, created: datetime | None = None) -> None:
            db, sess = _login_session(c)
            with db:
                sess.expires_at = expires
                if created is not None:
                    sess.created_at = created
                db.commit()

        now = datetime.now(UTC)
        set_times(now + timedelta(seconds=10))  # idle for almost 30 min
        assert c.get("/api/auth/me", headers=bearer).status_code == 200
        assert expiry() - now > timedelta(minutes=29)  # activity: the idle clock restarts
        # never past the absolute lifetime after the login
        set_times(now + timedelta(seconds=10), created=now - timedelta(hours=12, minutes=-5))
        assert c.get("/api/auth/me", headers=bearer).status_code == 200
        assert expiry() - now < timedelta(minutes=6)
        set_times(now - timedelta(seconds=1))  # idle too long
        r = c.get("/api/auth/me", headers=bearer)
        assert r.status_code == 401 and "idle" in r.json()["detail"]


def _until_closed(ws: Any) -> dict[str, Any]:
    """Read a websocket's messages until the server closes it; the close message."""
    for _ in range(100_000):  # bounded: a stream that never closes fails the test
        msg = ws.receive()
        if msg["type"] == "websocket.close":
            return dict(msg)
    raise AssertionError("the server never closed the websocket")


def test_logout_ends_open_live_and_3d_view_sockets(tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """A websocket is authenticated at its handshake only; the streams of a subject's
    images and skeletons must not outlive the logout of whoever opened them."""
    import viser

    from app.api import deps

    monkeypatch.setattr(deps, "SOCKET_LOGIN_CHECK_S", 0.05)
    s = _settings(tmp_path, viewer_enabled=True, viewer_port=0)
    with TestClient(create_app(s)) as c:
        bearer = {"Authorization": f"Bearer {_login(c).json()['token']}"}  # + the cookie
        with c.websocket_connect("/api/live/ws") as live, c.websocket_connect(
                "/viewer", subprotocols=[f"viser-v{viser.__version__}"]) as view:
            assert '"hello"' in live.receive_text()
            assert view.receive_bytes()  # viser streams the scene
            assert c.post("/api/auth/logout", headers=bearer).status_code == 204
            assert _until_closed(live)["code"] == 4401
            assert _until_closed(view)["code"] == 4401


# --------------------------------------------------------------------------- passwords


def _audit(client: TestClient, bearer: dict[str, str], action: str) -> list[dict[str, Any]]:
    r = client.get("/api/audit", params={"action": action}, headers=bearer)
    assert r.status_code == 200, r.text
    return list(r.json())


def test_password_change_policy_and_other_sessions_end(client: TestClient) -> None:
    other = {"Authorization": f"Bearer {_login(client).json()['token']}"}
    client.cookies.clear()  # another browser
    me = {"Authorization": f"Bearer {_login(client).json()['token']}"}
    client.cookies.clear()
    url = "/api/auth/password"
    r = client.post(url, headers=me, json={"current_password": "nope-nope-nope",
                                           "new_password": "a fine new passphrase"})
    assert r.status_code == 403 and "current password" in r.json()["detail"]
    for bad, why in [("short-pw", "at least 12"), ("admin-and-more-1", "user name"),
                     ("aaaaaaaaaaaaaaaa", "repeats"), (PASSWORD, "differ")]:
        r = client.post(url, headers=me, json={"current_password": PASSWORD,
                                               "new_password": bad})
        assert r.status_code == 422 and why in r.json()["detail"], (bad, r.text)
    r = client.post(url, headers=me, json={"current_password": PASSWORD,
                                           "new_password": "horse battery staple 7"})
    assert r.status_code == 200 and r.json() == {"other_sessions_ended": 1}, r.text
    assert client.get("/api/auth/me", headers=other).status_code == 401  # ended
    assert client.get("/api/auth/me", headers=me).status_code == 200  # this one stays
    assert client.post("/api/auth/login", json={"username": "admin", "password": PASSWORD}
                       ).status_code == 401
    _login(client, "horse battery staple 7")
    changes = _audit(client, me, "password_change")
    assert len(changes) == 1 and "1 other login" in changes[0]["detail"]


def test_first_run_password_policy_helper() -> None:
    from app.api.security import password_problem

    assert password_problem("correct horse battery", "admin") is None
    assert "12" in (password_problem("pw", "admin") or "")


# ----------------------------------------------------------------------------- logins


def test_failed_logins_same_answer_throttled_and_audited(client: TestClient) -> None:
    """Unknown user and wrong password answer alike (no user enumeration); after five
    failures the name is paused for that address (429) and the pause is in the trail."""
    unknown = client.post("/api/auth/login", json={"username": "nobody", "password": "x"})
    wrong = client.post("/api/auth/login", json={"username": "admin", "password": "x"})
    assert unknown.status_code == wrong.status_code == 401
    assert unknown.json() == wrong.json()
    for _ in range(4):
        assert client.post("/api/auth/login", json={"username": "admin", "password": "x"}
                           ).status_code == 401
    r = client.post("/api/auth/login", json={"username": "admin", "password": PASSWORD})
    assert r.status_code == 429 and int(r.headers["retry-after"]) > 0  # even the right one
    from app.api.security import LoginThrottle

    client.app.state.login_throttle = LoginThrottle(5, 300.0)  # type: ignore[attr-defined]
    bearer = {"Authorization": f"Bearer {_login(client).json()['token']}"}
    failed = _audit(client, bearer, "login_failed")
    assert len(failed) == 6
    assert sum("paused" in e["detail"] for e in failed) == 1


def test_password_spray_over_many_names_is_paused_per_address() -> None:
    from app.api.security import LoginThrottle

    th = LoginThrottle(max_failures=5, window_s=300.0)
    for k in range(19):
        th.failed(f"user{k}", "10.0.0.9", now=1000.0 + k)
    assert th.retry_after("user-new", "10.0.0.9", now=1020.0) == 0
    assert th.failed("user19", "10.0.0.9", now=1020.0)  # the 20th name: the address pauses
    assert th.retry_after("user-new", "10.0.0.9", now=1021.0) > 0
    assert th.retry_after("user-new", "10.0.0.10", now=1021.0) == 0  # others unaffected


# -------------------------------------------------------------------------- node link


def _hello(client: TestClient, node_id: str, token: str) -> dict[str, Any]:
    import json

    from app.nodes.protocol import Hello, dump

    with client.websocket_connect("/ws/node") as ws:
        ws.send_text(dump(Hello(node_id=node_id, token=token)))
        return dict(json.loads(ws.receive_text()))


def test_node_ids_that_name_folders_are_refused(client: TestClient) -> None:
    """A node's id becomes a folder under recordings/<rec_id>/: '.' and '..' would put its
    files into the recording's or all recordings' folder."""
    for bad in (".", ".."):
        m = _hello(client, bad, "review-node-token-1")
        assert m["type"] == "refused" and "not allowed" in m["reason"], m
    assert _hello(client, "S.1", "review-node-token-1")["type"] == "welcome"


def test_pairing_token_guessing_is_paused_per_address(client: TestClient) -> None:
    for k in range(5):
        m = _hello(client, "S1", f"guess-{k:08d}")
        assert m["type"] == "refused" and "wrong pairing token" in m["reason"]
    # the right token from the same address now waits too: guessing cannot go on
    m = _hello(client, "S1", "review-node-token-1")
    assert m["type"] == "refused" and "too many wrong pairing tokens" in m["reason"]
    client.app.state.hub._token_failures._failures.clear()  # type: ignore[attr-defined]
    assert _hello(client, "S1", "review-node-token-1")["type"] == "welcome"


def test_a_paused_address_is_told_to_come_back_later(client: TestClient) -> None:
    """A right node at an address paused for another process's guesses (sim nodes on one
    host, nodes behind one NAT) must retry after the pause: close code 1013, not the
    final 4401 of a wrong token, on which a node stops for good."""
    from app.nodes.protocol import Hello, dump

    def close_code(token: str) -> int:
        with client.websocket_connect("/ws/node") as ws:
            ws.send_text(dump(Hello(node_id="S1", token=token)))
            return int(_until_closed(ws)["code"])

    assert [close_code(f"guess-{k:08d}") for k in range(5)] == [4401] * 5
    assert close_code("review-node-token-1") == 1013


def test_anonymous_node_connections_are_bounded(client: TestClient) -> None:
    """Connections that have not said hello yet (each may send one large message before
    it is checked) are capped; the next one is told to come back later."""
    import contextlib
    import json

    from app.server.hub import MAX_PENDING_HELLOS

    with contextlib.ExitStack() as stack:
        for _ in range(MAX_PENDING_HELLOS):
            stack.enter_context(client.websocket_connect("/ws/node"))
        with client.websocket_connect("/ws/node") as ws:
            m = json.loads(ws.receive_text())
            assert m["type"] == "refused" and "try again" in m["reason"], m
    # once they are gone, a node pairs as usual
    assert _hello(client, "S1", "review-node-token-1")["type"] == "welcome"


def test_image_headers_declaring_huge_sizes_are_refused(client: TestClient) -> None:
    """A few bytes of PNG or JPEG can declare 60000×60000 pixels; the decoder would
    allocate gigabytes for it. The hub reads the header first and refuses the image."""
    import json
    import struct
    import zlib

    import cv2
    import numpy as np

    from app.nodes.protocol import Hello, dump, encode_binary
    from app.server.hub import image_size

    ok_png = cv2.imencode(".png", np.zeros((424, 512), np.uint16))[1].tobytes()
    ok_jpg = cv2.imencode(".jpg", np.zeros((1080, 1920, 3), np.uint8))[1].tobytes()
    assert image_size(ok_png) == (512, 424) and image_size(ok_jpg) == (1920, 1080)
    ihdr = struct.pack(">IIBBBBB", 60000, 60000, 16, 0, 0, 0, 0)
    bomb_png = (b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + b"IHDR" + ihdr
                + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr)))
    sof = ok_jpg.index(b"\xff\xc0")
    bomb_jpg = ok_jpg[:sof + 5] + struct.pack(">HH", 60000, 60000) + ok_jpg[sof + 9:]
    assert image_size(bomb_jpg) == (60000, 60000)
    with client.websocket_connect("/ws/node") as ws:
        ws.send_text(dump(Hello(node_id="S1", token="review-node-token-1")))
        assert json.loads(ws.receive_text())["type"] == "welcome"
        for stream, data in [("depth", bomb_png), ("color", bomb_jpg)]:
            ws.send_bytes(encode_binary({"kind": "image", "stream": stream, "t": 1.0,
                                         "format": "png"}, data))
            while (m := json.loads(ws.receive_text()))["type"] == "ping":
                pass
            assert m["type"] == "error" and "60000×60000" in m["reason"], m
        session = client.app.state.hub.registry.nodes["S1"]  # type: ignore[attr-defined]
        assert not session.images  # neither was kept
        ws.send_bytes(encode_binary({"kind": "image", "stream": "depth", "t": 1.0,
                                     "format": "png"}, ok_png))
        ws.send_bytes(encode_binary({"kind": "image", "stream": "color", "t": 1.0,
                                     "format": "png"}, bomb_png))
        while (m := json.loads(ws.receive_text()))["type"] == "ping":
            pass  # the refusal of the second comes after the first was taken
        assert m["type"] == "error"
        assert set(session.images) == {"depth"}  # the genuine image was


# ------------------------------------------------------------------- production start


def test_network_facing_server_refuses_shipped_token_and_weak_password(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from app.cli import main
    from app.config import DEFAULT_NODE_TOKEN
    from engine.errors import InputError

    with pytest.raises(InputError, match="change-me-node-token"):
        create_app(_settings(tmp_path, host="0.0.0.0", node_token=DEFAULT_NODE_TOKEN))
    with pytest.raises(InputError, match="ADMIN_PASSWORD is too weak"):
        create_app(_settings(tmp_path, host="10.1.2.3", admin_password="admin123"))
    # a strong password or none (generated and printed): fine on the network
    create_app(_settings(tmp_path, host="0.0.0.0", admin_password="tall green tripods 4"))
    create_app(_settings(tmp_path, host="0.0.0.0", admin_password=None))
    # one workstation (loopback): the demo's and the tests' short settings stay allowed
    create_app(_settings(tmp_path, host="127.0.0.1", node_token=DEFAULT_NODE_TOKEN,
                         admin_password="pw"))
    # `gaitrig serve` says what to change instead of a traceback
    code = main(["serve", "--host", "0.0.0.0", "--no-viewer", "--data-dir", str(tmp_path),
                 "--token", DEFAULT_NODE_TOKEN])
    assert code == 2
    err = capsys.readouterr().err
    assert "GAITRIG_NODE_TOKEN" in err and "Traceback" not in err


# ----------------------------------------------------------------------- error answers


def test_an_unexpected_error_leaks_no_internals(tmp_path: Path,
                                                caplog: pytest.LogCaptureFixture) -> None:
    """A bug answers 500 with a reference to the server log: no traceback, path or SQL."""
    from fastapi import APIRouter

    app = create_app(_settings(tmp_path))
    boom = APIRouter()

    @boom.get("/api/boom-for-test")
    def _boom() -> None:
        raise RuntimeError(f"SELECT * FROM subjects WHERE code='P01' -- {tmp_path}/gaitrig.db")

    app.router.routes.insert(0, boom.routes[0])
    with TestClient(app, raise_server_exceptions=False) as c:
        r = c.get("/api/boom-for-test")
    assert r.status_code == 500
    detail = r.json()["detail"]
    assert "reference" in detail
    for leak in ("SELECT", str(tmp_path), "Traceback", "RuntimeError", ".py"):
        assert leak not in r.text, leak
    assert r.headers["cache-control"] == "no-store"
    ref = detail.split("reference ")[1].split(")")[0]
    assert any(ref in rec.getMessage() for rec in caplog.records)  # findable in the log


def _c3d_param(raw: bytes, group: str, name: str) -> int:
    """Byte offset of the data of C3D parameter ``group:name`` (the parameter section:
    records of name length, group id, name, offset to the next record, type, dims)."""
    import struct

    off, groups, found = (raw[0] - 1) * 512 + 4, {}, {}
    while True:
        nlen, gid = struct.unpack_from("bb", raw, off)
        if nlen == 0:
            break
        label = bytes(raw[off + 2: off + 2 + abs(nlen)]).decode()
        nxt_at = off + 2 + abs(nlen)
        if gid < 0:
            groups[-gid] = label
        else:
            ndim = raw[nxt_at + 3]
            found[(gid, label)] = nxt_at + 4 + ndim
        nxt = struct.unpack_from("<h", raw, nxt_at)[0]
        if nxt == 0:
            break
        off = nxt_at + nxt
    gid = next(k for k, v in groups.items() if v == group)
    return int(found[(gid, name)])


def test_uploaded_file_names_are_never_paths(client: TestClient, tmp_path: Path,
                                             shared_data: Path) -> None:
    """A reference upload named '../../x.c3d' is stored under a random name in the
    recording's folder; a C3D whose parameters claim 32000 markers reads only what the
    file holds (ezc3d stops at the end of the data) instead of allocating for the claim."""
    import struct

    from app.db import data as m

    _login(client)
    sid = _subject(client, "UPL01")
    sess = client.post("/api/sessions", json={"subject_id": sid}).json()
    with client.app.state.db_sessions() as db:  # type: ignore[attr-defined]
        db.add(m.Recording(id="R1", session_id=sess["id"], state="complete", streams=""))
        db.commit()
    raw = bytearray((shared_data / "mocap" / "kineticstoolkit" / "walk.c3d").read_bytes())
    struct.pack_into("<h", raw, _c3d_param(bytes(raw), "POINT", "USED"), 32000)  # beyond the data
    before = {p for p in tmp_path.rglob("*") if p.is_file()}
    r = client.post("/api/exports/R1/references", headers={"Origin": BASE},
                    files={"file": ("../../../../evil.c3d", bytes(raw))})
    # (422: read, but the gait analysis finds no steps in what it holds)
    assert r.status_code in (201, 400, 422), r.text
    assert str(tmp_path) not in r.text
    if r.status_code == 201:
        assert r.json()["filename"] == "evil.c3d"
        assert r.json()["n_frames"] < 1000  # what the file holds, not the claim
    new = {p for p in tmp_path.rglob("*") if p.is_file()} - before
    assert not (tmp_path.parent / "evil.c3d").exists()
    for p in new:
        assert "evil" not in p.name, p  # stored under a random name, inside data_dir


# ---------------------------------------------------------------------------- accounts


def test_accounts_per_person_are_managed_by_administrators(client: TestClient) -> None:
    """One account per person (the trail names people, not a shared 'admin'): created,
    reset and removed by an administrator only, each audited; a nurse cannot."""
    admin = {"Authorization": f"Bearer {_login(client).json()['token']}"}
    client.cookies.clear()
    r = client.post("/api/users", headers=admin,
                    json={"username": "a.nurse", "password": "short"})
    assert r.status_code == 422 and "12" in r.json()["detail"]
    r = client.post("/api/users", headers=admin,
                    json={"username": "a.nurse", "password": "walking gait lab 3"})
    assert r.status_code == 201, r.text
    assert client.post("/api/users", headers=admin, json={
        "username": "A.Nurse", "password": "walking gait lab 3"}).status_code == 409
    r = client.post("/api/auth/login", json={"username": "a.nurse",
                                             "password": "walking gait lab 3"})
    nurse = {"Authorization": f"Bearer {r.json()['token']}"}
    client.cookies.clear()
    for method, url, body in [("GET", "/api/users", None),
                              ("POST", "/api/users", {"username": "x.y",
                                                      "password": "walking gait lab 4"}),
                              ("POST", "/api/users/admin/password",
                               {"new_password": "walking gait lab 5"}),
                              ("POST", "/api/users/admin/delete", {"confirm": "admin"})]:
        r = client.request(method, url, headers=nurse, json=body)
        assert r.status_code == 403, (url, r.text)
    listed = {u["username"]: u for u in client.get("/api/users", headers=admin).json()}
    assert listed["a.nurse"]["open_logins"] == 1 and not listed["a.nurse"]["is_admin"]
    # a reset ends the nurse's logins
    r = client.post("/api/users/a.nurse/password", headers=admin,
                    json={"new_password": "another walk 42"})
    assert r.status_code == 204
    assert client.get("/api/auth/me", headers=nurse).status_code == 401
    # neither oneself nor the last administrator can be removed
    assert client.post("/api/users/admin/delete", headers=admin,
                       json={"confirm": "admin"}).status_code == 409
    assert client.post("/api/users/a.nurse/delete", headers=admin,
                       json={"confirm": "wrong"}).status_code == 400
    assert client.post("/api/users/a.nurse/delete", headers=admin,
                       json={"confirm": "a.nurse"}).status_code == 200
    assert client.post("/api/auth/login", json={"username": "a.nurse",
                                                "password": "another walk 42"}
                       ).status_code == 401
    trail = [e["detail"] for e in _audit(client, admin, "account")]
    assert trail == ["removed", "password set by an administrator; 1 login ended",
                     "created"]


def test_passwords_are_stored_at_owasps_scrypt_cost_by_default(monkeypatch: pytest.MonkeyPatch
                                                               ) -> None:
    """The shipped cost is OWASP's N = 2**17 (the suite runs at a lower one for speed)."""
    from app.api.security import hash_cost, hash_password, verify_password

    monkeypatch.delenv("GAITRIG_PASSWORD_HASH_COST", raising=False)
    assert Settings().password_hash_cost == 17
    stored = hash_password("a correct horse staple")
    assert stored.startswith("scrypt$131072$8$1$") and hash_cost(stored) == 17
    assert verify_password("a correct horse staple", stored)
    assert not verify_password("a correct horse stapler", stored)


def test_a_login_rehashes_a_password_stored_at_a_lower_cost(tmp_path: Path) -> None:
    """Raising the setting needs no password reset: the next login re-hashes."""
    from sqlalchemy import select

    from app.api.security import hash_cost
    from app.db.models import User

    def stored(c: TestClient) -> str:
        with c.app.state.db_sessions() as db:  # type: ignore[attr-defined]
            return str(db.scalar(select(User.password_hash)))

    with TestClient(create_app(_settings(tmp_path, password_hash_cost=12))) as c:
        assert hash_cost(stored(c)) == 12
    with TestClient(create_app(_settings(tmp_path, password_hash_cost=14))) as c:
        assert hash_cost(stored(c)) == 12  # unchanged until its owner logs in
        r = c.post("/api/auth/login", json={"username": "admin", "password": "wrong-pw-0000"})
        assert r.status_code == 401 and hash_cost(stored(c)) == 12
        _login(c)
        assert hash_cost(stored(c)) == 14
        c.post("/api/auth/logout")
        _login(c)  # the new hash verifies
