"""Clinical-data safety of the HTTP API: every route needs a login (but an explicit
allow-list), malformed path parameters and JSON bodies get a readable 4xx, request sizes
are bounded, and a rejected upload changes nothing already stored.

The routes are enumerated from ``app.routes`` (flattened, websockets and mounts included),
so a route added later is checked without editing this file.
"""

from __future__ import annotations

import json
import os
import re
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi import APIRouter, FastAPI, UploadFile
from fastapi.routing import APIRoute, iter_route_contexts
from fastapi.testclient import TestClient
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.websockets import WebSocketDisconnect

from app.api.limits import JSON_BODY_MAX, BoundedRoute
from app.config import Settings
from app.main import create_app

PASSWORD = "safety-pw-123"

#: (method, path) that answer without a login, and why. A route missing here and not
#: refusing an anonymous request fails the test; so does an entry no route matches.
ALLOWED_WITHOUT_LOGIN: dict[tuple[str, str], str] = {
    ("POST", "/api/auth/login"): "how one logs in",
    ("GET", "/api/auth/session"): "whether the caller is logged in: {logged_in: false} and "
                                  "nothing else without a login (pages open without one, "
                                  "like Help, ask it)",
    ("GET", "/healthz"): "liveness probe for compose/monitoring: answers {'status': 'ok'} only",
    ("GET", "/"): "redirect to the console page, which itself asks /api (login required)",
    ("GET", "/openapi.json"): "API description (no data), used by /docs",
    ("GET", "/docs"): "interactive API description page (no data)",
    ("GET", "/docs/oauth2-redirect"): "static helper page of /docs (no data)",
    ("GET", "/redoc"): "API description page (no data)",
    ("MOUNT", "/"): "static console (HTML/JS/CSS incl. the login form, no data); every "
                    "page reads data from /api, which needs a login",
}

#: Websockets that authenticate by their own token instead of the console login.
TOKEN_WEBSOCKETS: dict[str, str] = {
    "/ws/node": "sensor nodes authenticate with the pairing token (settings.node_token)",
    "/api/kscc/link": "another site authenticates with a per-node link token",
}

#: Path parameter values a client might send by mistake or malice.
BAD_PATH_VALUES = [
    "..%2F..%2Fetc%2Fpasswd",  # (a bare ".." is resolved away by the client itself)
    "%2e%2e",
    "%00",
    "a%00b",
    "x" * 5000,
    "%C3%BC%E2%9C%93%F0%9F%A6%B6",  # ü✓🦶
    "-1",
    "0",
    "99999999999999999999999999",
    "1e400",
    "nope-does-not-exist",
    "%20",
]

#: Field values of the wrong type (or far out of range) for any JSON body field.
WRONG_FIELD_VALUES: list[Any] = [[[[]]], {"a": {"b": []}}, -10**30, "\u2603" * 3, None]


def _settings(tmp_path: Path) -> Settings:
    return Settings(data_dir=tmp_path, viewer_enabled=False, admin_password=PASSWORD,
                    node_token="safety-node-token-123", calibration_check_interval_s=0)


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    with TestClient(create_app(_settings(tmp_path)), raise_server_exceptions=False) as c:
        yield c


def _login(client: TestClient) -> dict[str, str]:
    r = client.post("/api/auth/login", json={"username": "admin", "password": PASSWORD})
    assert r.status_code == 200, r.text
    client.cookies.clear()  # tests pass the bearer token explicitly
    return {"Authorization": f"Bearer {r.json()['token']}"}


def _routes(client: TestClient) -> list[Any]:
    routes = list(iter_route_contexts(client.app.routes))  # type: ignore[attr-defined]
    assert len(routes) > 60, "route enumeration is broken"
    return routes


def _http_routes(client: TestClient) -> list[tuple[str, str, Any]]:
    out = []
    for r in _routes(client):
        if isinstance(r.original_route, (APIRoute, Route)):
            for m in sorted(r.methods or ()):
                if m != "HEAD":
                    out.append((m, r.path, r))
    return out


def _fill(path: str, value: str) -> str:
    return re.sub(r"\{[^}]+\}", value, path)


def _assert_readable(r: Any, what: str) -> None:
    """A 4xx with a JSON ``detail`` a person can read (no traceback)."""
    assert r.status_code < 500, f"{what}: {r.status_code} {r.text[:300]}"
    assert r.status_code >= 400, f"{what}: accepted ({r.status_code})"
    try:
        body = r.json()
    except ValueError:
        pytest.fail(f"{what}: {r.status_code} answer is not JSON: {r.text[:200]!r}")
    detail = body.get("detail") if isinstance(body, dict) else None
    assert isinstance(detail, str) and detail.strip(), f"{what}: no readable detail: {body}"
    assert "Traceback" not in r.text and 'File "' not in r.text, f"{what}: traceback"


# ------------------------------------------------------------------------- 1. auth


def test_every_route_refuses_anonymous_requests(client: TestClient) -> None:
    seen_allowed: set[tuple[str, str]] = set()
    checked = 0
    for method, path, _ in _http_routes(client):
        if (method, path) in ALLOWED_WITHOUT_LOGIN:
            seen_allowed.add((method, path))
            continue
        url = _fill(path, "1")
        for headers in ({}, {"Authorization": "Bearer not-a-token"},
                        {"Cookie": "gaitrig_session=not-a-token"}):
            r = client.request(method, url, headers=headers)
            assert r.status_code in (401, 403), (
                f"{method} {path} answers {r.status_code} without a login; require "
                "CurrentUser or add it to ALLOWED_WITHOUT_LOGIN with a reason")
            _assert_readable(r, f"{method} {path}")
        checked += 1
    mounts = [r for r in _routes(client) if isinstance(r.original_route, Mount)]
    for m in mounts:
        key = ("MOUNT", m.path or "/")
        assert key in ALLOWED_WITHOUT_LOGIN, f"mount {key[1]} is not in the allow-list"
        seen_allowed.add(key)
    stale = set(ALLOWED_WITHOUT_LOGIN) - seen_allowed
    assert not stale, f"allow-list entries without a route (remove them): {stale}"
    assert checked > 60


def test_websockets_refuse_anonymous_clients(client: TestClient) -> None:
    ws_paths = {r.path for r in _routes(client)
                if isinstance(r.original_route, WebSocketRoute)
                or type(r.original_route).__name__ == "APIWebSocketRoute"}
    assert ws_paths >= {"/api/live/ws", *TOKEN_WEBSOCKETS}
    for path in sorted(ws_paths):
        if path in TOKEN_WEBSOCKETS:
            with client.websocket_connect(path) as ws:
                ws.send_text(json.dumps({"type": "hello", "node_id": "S1",
                                         "token": "wrong-token-000000", "protocol": 1}))
                m = json.loads(ws.receive_text())
                assert m["type"] == "refused", f"{path} accepted a wrong token: {m}"
            continue
        # console websockets need the session cookie
        for cookie in (None, "not-a-token"):
            if cookie:
                client.cookies.set("gaitrig_session", cookie)
            with pytest.raises(WebSocketDisconnect) as exc, \
                    client.websocket_connect(path) as ws:
                ws.receive_text()
            assert exc.value.code == 4401, f"{path} without a login: close {exc.value.code}"
            client.cookies.clear()


def test_unauthenticated_3d_view_is_local_by_default() -> None:
    """The viser server itself has no login: it shows live skeletons, so it listens on the
    loopback interface by default and the console reaches it through ``/viewer`` (checked
    above with the other routes); opening viser's own port to the network is an explicit
    ``GAITRIG_VIEWER_HOST``."""
    assert Settings.model_fields["viewer_host"].default in ("127.0.0.1", "localhost", "::1")


def test_static_mount_serves_no_file_outside_the_console(client: TestClient,
                                                         tmp_path: Path) -> None:
    (tmp_path / "secret.txt").write_text("patient")
    for url in ("/..%2Fpyproject.toml", "/%2e%2e/pyproject.toml", "/..%2F..%2Fetc%2Fpasswd",
                "/css/..%2F..%2Fpyproject.toml", "/%00", "/api/nope/..%2F..%2Fsecret.txt"):
        r = client.get(url)
        assert r.status_code in (400, 404), f"{url}: {r.status_code}"
        assert "patient" not in r.text and "[project]" not in r.text and "root:" not in r.text


# --------------------------------------------------------------- 2. malformed input


def test_malformed_path_parameters_get_a_readable_4xx(client: TestClient) -> None:
    h = _login(client)
    n = 0
    for method, path, _ in _http_routes(client):
        if "{" not in path or not path.startswith("/api/"):
            continue
        for value in BAD_PATH_VALUES:
            url = _fill(path, value)
            r = client.request(method, url, headers=h, json={} if method != "GET" else None)
            if r.status_code in (404, 405) and r.headers.get("content-type", "").startswith(
                    "text/plain"):
                pytest.fail(f"{method} {url[:120]}: plain-text {r.status_code}")
            _assert_readable(r, f"{method} {path} with {value[:30]!r}")
            n += 1
    assert n > 300


#: Query values a client might send by mistake or malice.
BAD_QUERY_VALUES = ["nan", "inf", "-1", "1e999", "x" * 5000, "\x00", "\u2603", "", ",,,",
                    "99999999999999999999999", "../../etc/passwd", "0-10000000000000"]


def test_malformed_query_parameters_get_a_readable_4xx(client: TestClient) -> None:
    h = _login(client)
    _filed_recording(client, h, "R1")
    n = 0
    for method, path, ctx in _http_routes(client):
        route = ctx.original_route
        if not isinstance(route, APIRoute) or not path.startswith("/api/"):
            continue
        url = _fill(path, "R1" if "rec_id" in path else "1")
        for q in (p.name for p in route.dependant.query_params):
            for v in BAD_QUERY_VALUES:
                r = client.request(method, url, params={q: v}, headers=h)
                if r.status_code < 400:
                    continue  # a value that happens to be valid (e.g. tilt_deg=-1)
                _assert_readable(r, f"{method} {path}?{q}={v[:20]!r}")
                n += 1
    assert n > 100


def _json_body_fields(route: APIRoute) -> list[str] | None:
    """Field names of a route's JSON body model, None when it takes no JSON body."""
    params = route.dependant.body_params
    if not params:
        return None
    info = params[0].field_info
    if type(info).__name__ in ("File", "Form"):
        return None
    ann = params[0].field_info.annotation
    return list(getattr(ann, "model_fields", {})) or ["value"]


def test_malformed_json_bodies_get_a_readable_4xx(client: TestClient) -> None:
    h = _login(client)
    n = 0
    for method, path, ctx in _http_routes(client):
        route = ctx.original_route
        if not isinstance(route, APIRoute) or path == "/api/auth/login":
            continue
        fields = _json_body_fields(route)
        if fields is None:
            continue
        url = _fill(path, "1")
        raw_bodies = [b"", b"{", b"null", b"[]", b'"x"', b"42", b'{"a":', b"\xff\xfe"]
        for raw in raw_bodies:
            r = client.request(method, url, headers={**h, "Content-Type": "application/json"},
                               content=raw)
            _assert_readable(r, f"{method} {path} body {raw!r}")
            n += 1
        for f in fields:
            for v in WRONG_FIELD_VALUES:
                r = client.request(method, url, headers=h, json={f: v})
                if r.status_code < 400:
                    continue  # a value that happens to be valid for this field
                _assert_readable(r, f"{method} {path} {{{f}: {v!r}}}")
                n += 1
    assert n > 100


def test_json_bodies_are_bounded(client: TestClient) -> None:
    """Every route refuses a JSON body far beyond any real request with a readable 413,
    and nothing is stored."""
    h = _login(client)
    huge = json.dumps({"name": "x" * (JSON_BODY_MAX + 10), "description": ""})
    before = client.get("/api/projects", headers=h).json()
    n = 0
    for method, path, ctx in _http_routes(client):
        route = ctx.original_route
        if not path.startswith("/api/"):
            continue
        assert isinstance(route, BoundedRoute), (
            f"{method} {path}: create its router with route_class=BoundedRoute")
        if _json_body_fields(route) is None:
            continue
        r = client.request(method, _fill(path, "1"),
                           headers={**h, "Content-Type": "application/json"}, content=huge)
        assert r.status_code == 413, f"{method} {path}: {r.status_code} {r.text[:200]}"
        _assert_readable(r, f"{method} {path} huge body")
        assert "1 MB" in r.json()["detail"], r.json()
        n += 1
    assert n > 20
    assert client.get("/api/projects", headers=h).json() == before


def test_bounded_route_counts_bodies_without_content_length() -> None:
    """The limit holds for a streamed (chunked) body and for a multipart upload, with the
    route's own ``max_body_size`` overriding the JSON default."""
    app = FastAPI()
    probe = APIRouter(route_class=BoundedRoute)

    @probe.post("/json")
    def take_json(body: dict[str, Any]) -> int:
        return len(body)

    @probe.post("/upload", max_body_size=4096)
    async def take_file(file: UploadFile) -> int:
        return len(await file.read())

    app.include_router(probe)
    with TestClient(app, raise_server_exceptions=False) as c:
        def chunks(total: int) -> Iterator[bytes]:
            yield b'{"a": "'
            for _ in range(total // 65536):
                yield b"x" * 65536
            yield b'"}'

        r = c.post("/json", content=chunks(JSON_BODY_MAX + 65536),
                   headers={"Content-Type": "application/json"})
        assert r.status_code == 413 and "1 MB" in r.json()["detail"], r.text
        assert c.post("/json", content=chunks(65536),
                      headers={"Content-Type": "application/json"}).json() == 1
        r = c.post("/upload", files={"file": ("a.csv", b"x" * 5000, "text/csv")})
        assert r.status_code == 413 and "4 KB" in r.json()["detail"], r.text
        assert c.post("/upload", files={"file": ("a.csv", b"x" * 3000, "text/csv")}
                      ).json() == 3000
        # a body bigger than the upload limit but not the JSON one: the route's limit wins
        def multipart(size: int) -> Iterator[bytes]:
            yield (b'--x\r\nContent-Disposition: form-data; name="file"; filename="a.csv"'
                   b"\r\nContent-Type: text/csv\r\n\r\n")
            for _ in range(size // 1000):
                yield b"x" * 1000
            yield b"\r\n--x--\r\n"

        mp = {"Content-Type": "multipart/form-data; boundary=x"}
        r = c.post("/upload", content=multipart(20000), headers=mp)
        assert r.status_code == 413 and "4 KB" in r.json()["detail"], r.text
        assert c.post("/upload", content=multipart(3000), headers=mp).json() == 3000


def test_int_ids_beyond_the_database_range_are_404(client: TestClient) -> None:
    h = _login(client)
    big = str(2**70)
    for method, url in (("GET", f"/api/subjects/{big}"), ("GET", f"/api/sessions/{big}"),
                        ("PATCH", f"/api/projects/{big}"), ("GET", f"/api/calibration/{big}"),
                        ("GET", f"/api/reports/subjects/{big}"),
                        ("GET", f"/api/subjects?project_id={big}"),
                        ("GET", f"/api/sessions?subject_id={big}")):
        r = client.request(method, url, headers=h, json={} if method != "GET" else None)
        _assert_readable(r, f"{method} {url}")
    r = client.post("/api/sessions", headers=h, json={"subject_id": 2**70})
    _assert_readable(r, "POST /api/sessions with a huge subject id")
    r = client.post("/api/subjects", headers=h, json={"project_id": 2**70, "code": "P1"})
    _assert_readable(r, "POST /api/subjects with a huge project id")


# ------------------------------------------------------------------------ 3. uploads


def _skeleton_csv() -> bytes:
    """A small valid skeleton CSV of a walk (Kinect v2 joints): a reference the Subjects
    page accepts (one standing still has no steps, and is refused)."""
    from tests.app.mocap_files import walk_skeleton_csv

    return walk_skeleton_csv()


def _filed_recording(client: TestClient, h: dict[str, str], rec_id: str) -> None:
    from app.db import data as m

    pid = client.post("/api/projects", headers=h, json={"name": "safety"}).json()["id"]
    sid = client.post("/api/subjects", headers=h, json={"project_id": pid, "code": "P1"}
                      ).json()["id"]
    se = client.post("/api/sessions", headers=h, json={"subject_id": sid}).json()["id"]
    with client.app.state.db_sessions() as db:  # type: ignore[attr-defined]
        db.add(m.Recording(id=rec_id, session_id=se, state="complete"))
        db.commit()


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file() and p.suffix != ".sqlite3"
            and "sqlite3" not in p.name}


def test_reference_import_limits_and_rollback(client: TestClient, tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    from app.api.routes import _reference

    h = _login(client)
    _filed_recording(client, h, "R1")
    good = _skeleton_csv()
    r = client.post("/api/exports/R1/references", headers=h,
                    files={"file": ("walk.csv", good, "text/csv")})
    assert r.status_code == 201, r.text
    refs = client.get("/api/exports/R1/references", headers=h).json()
    files = _tree(tmp_path)
    monkeypatch.setattr(_reference, "MAX_REFERENCE_BYTES", len(good) + 100)
    for name, data, status in (
            ("big.csv", good + b"x" * 500, 413),
            ("bad.c3d", b"not a c3d file at all", 400),
            ("bad.trc", b"PathFileType\t4\n\x00\x01", 400),
            ("bad.csv", b"time,a\n1,2\n", 400),
            ("empty.csv", b"", 400),
            ("walk.exe", good, 400),
            ("../../etc/passwd.csv", b"root:x:0:0", 400)):
        r = client.post("/api/exports/R1/references", headers=h,
                        files={"file": (name, data, "application/octet-stream")})
        assert r.status_code == status, f"{name}: {r.status_code} {r.text[:200]}"
        _assert_readable(r, f"reference {name}")
        if status == 413:
            assert "MB" in r.json()["detail"] or "KB" in r.json()["detail"]
    assert client.get("/api/exports/R1/references", headers=h).json() == refs
    assert _tree(tmp_path) == files
    assert client.get(f"/api/exports/R1/references/{refs[0]['id']}", headers=h).content == good


def test_a_reference_upload_is_never_under_its_final_name_before_its_row(
        client: TestClient, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The upload was written under its final name: a backup during the upload took a
    half-written file, and one that failed after the write (the row's commit) left an
    orphan. It is written as *.tmp (backups skip those) and renamed once committed."""
    import sqlalchemy.exc
    from sqlalchemy.orm import Session

    from app.server import storage

    h = _login(client)
    _filed_recording(client, h, "R1")
    folder = tmp_path / "references" / "R1"
    seen: list[list[str]] = []
    real_read = storage.parse_reference

    def read(path: Path, fmt: str) -> Any:
        seen.append(sorted(p.name for p in folder.iterdir()))
        return real_read(path, fmt)

    # (the check shared with the Reports page's upload reads it: app.api.routes._reference)
    monkeypatch.setattr(storage, "parse_reference", read)
    r = client.post("/api/exports/R1/references", headers=h,
                    files={"file": ("walk.csv", _skeleton_csv(), "text/csv")})
    assert r.status_code == 201, r.text
    assert len(seen) == 1 and len(seen[0]) == 1 and seen[0][0].endswith(".tmp"), seen
    stored = sorted(p.name for p in folder.iterdir())
    assert len(stored) == 1 and not stored[0].endswith(".tmp")
    d = client.get(f"/api/exports/R1/references/{r.json()['id']}", headers=h)
    assert d.content == _skeleton_csv()
    refs = client.get("/api/exports/R1/references", headers=h).json()

    def fail_commit(self: Session) -> None:
        raise sqlalchemy.exc.OperationalError("COMMIT", {}, Exception("disk I/O error"))

    with monkeypatch.context() as mp:
        mp.setattr(Session, "commit", fail_commit)
        r = client.post("/api/exports/R1/references", headers=h,
                        files={"file": ("walk2.csv", _skeleton_csv(), "text/csv")})
    assert r.status_code >= 400
    assert sorted(p.name for p in folder.iterdir()) == stored  # nothing left behind
    assert client.get("/api/exports/R1/references", headers=h).json() == refs
    # a temporary file of a server killed mid-upload is removed by a later upload
    orphan = folder / ".0123456789abcdef.csv.upload.tmp"
    orphan.write_bytes(b"half")
    os.utime(orphan, (time.time() - 3 * 86400,) * 2)
    r = client.post("/api/exports/R1/references", headers=h,
                    files={"file": ("walk3.csv", _skeleton_csv(), "text/csv")})
    assert r.status_code == 201, r.text
    assert not orphan.exists()


def test_a_report_reference_being_checked_is_not_in_a_backup(
        client: TestClient, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The report reference was checked in a plain temporary folder inside the recording's
    (a backup then took the half-checked upload, a killed server left it) and its meta.json
    written after the file was in place. Now the whole new folder is swapped in."""
    from app.api.routes import reports
    from app.server import backup
    from tests.app.mocap_files import walk_skeleton_c3d

    h = _login(client)
    ref = _planted_report_reference(tmp_path)
    files = _tree(tmp_path)
    in_backup: list[list[str]] = []
    walk, _ = walk_skeleton_c3d()  # a file its reader takes: the analysis is checked next

    def steps(path: Path, **_: Any) -> Any:
        in_backup.append([str(r) for r, _ in backup._walk(tmp_path, [], set())])
        raise reports.InsufficientDataError("no steps in this walk")

    monkeypatch.setattr(reports.an, "reference_steps", steps)
    r = client.post("/api/reports/recordings/R2/reference", headers=h,
                    files={"file": ("walk.c3d", walk, "application/octet-stream")})
    assert r.status_code == 422, r.text  # readable, no walk in it (as on the Subjects page)
    assert "'old.csv' stays attached" in r.json()["detail"], r.text
    assert in_backup and not [n for n in in_backup[0] if "upload" in n], in_backup
    assert _tree(tmp_path) == files  # nothing left behind, the old reference kept
    monkeypatch.setattr(reports.an, "reference_steps", lambda path, **_: [1, 2, 3, 4])
    r = client.post("/api/reports/recordings/R2/reference?offset_s=1.5", headers=h,
                    files={"file": ("new.c3d", walk, "application/octet-stream")})
    assert r.status_code == 201, r.text
    assert sorted(p.name for p in (tmp_path / "recordings" / "R2").iterdir()) == [
        "S1", "reference"]
    assert (ref / "reference.c3d").read_bytes() == walk
    assert not (ref / "reference.csv").exists()
    got = client.get("/api/reports/recordings/R2/reference", headers=h).json()
    assert got["attached"] and got["filename"] == "new.c3d" and got["n_steps"] == 4
    # a killed server's temporary folder is removed by a later upload
    stale = tmp_path / "recordings" / "R2" / ".reference-upload-x.tmp"
    stale.mkdir()
    (stale / "upload.c3d").write_bytes(b"half")
    os.utime(stale, (time.time() - 3 * 86400,) * 2)
    r = client.post("/api/reports/recordings/R2/reference", headers=h,
                    files={"file": ("new.c3d", walk, "application/octet-stream")})
    assert r.status_code == 201, r.text
    assert not stale.exists()


def test_reference_whose_file_is_gone_is_a_404(client: TestClient, tmp_path: Path) -> None:
    h = _login(client)
    _filed_recording(client, h, "R1")
    r = client.post("/api/exports/R1/references", headers=h,
                    files={"file": ("walk.csv", _skeleton_csv(), "text/csv")})
    assert r.status_code == 201, r.text
    for f in (tmp_path / "references" / "R1").iterdir():
        f.unlink()
    d = client.get(f"/api/exports/R1/references/{r.json()['id']}", headers=h)
    assert d.status_code == 404, d.text
    _assert_readable(d, "download of a reference whose file is gone")
    assert "upload it again" in d.json()["detail"]
    d = client.post(f"/api/exports/R1/references/{r.json()['id']}/delete", headers=h)
    assert d.status_code == 200 and client.get("/api/exports/R1/references", headers=h
                                               ).json() == []


def test_reference_with_a_non_ascii_name_downloads(client: TestClient) -> None:
    """HTTP headers are Latin-1: the download of "Gang_Müller ✓.csv" was a 500."""
    from urllib.parse import quote

    h = _login(client)
    _filed_recording(client, h, "R1")
    name = 'Gang_Müller ✓ "2".csv'
    r = client.post("/api/exports/R1/references", headers=h,
                    files={"file": (name, _skeleton_csv(), "text/csv")})
    assert r.status_code == 201, r.text
    stored = r.json()["filename"]  # as the client encoded it (httpx: '"' -> %22)
    d = client.get(f"/api/exports/R1/references/{r.json()['id']}", headers=h)
    assert d.status_code == 200, d.text
    cd = d.headers["content-disposition"]
    assert cd.startswith('attachment; filename="Gang_M_ller _ ') and "\n" not in cd
    assert cd.endswith("filename*=UTF-8''" + quote(stored, safe=""))


def _planted_report_reference(data_dir: Path) -> Path:
    """Recording R2 with one part and a report reference (``reference.csv`` = b"kept");
    returns the reference folder."""
    part = data_dir / "recordings" / "R2" / "S1"
    part.mkdir(parents=True)
    (part / "frames.bin").write_bytes(b"")
    (part / "meta.json").write_text("{}")
    ref = data_dir / "recordings" / "R2" / "reference"
    ref.mkdir()
    (ref / "reference.csv").write_bytes(b"kept")
    (ref / "meta.json").write_text(json.dumps({"filename": "old.csv", "ext": ".csv",
                                               "offset_s": 0.0, "n_steps": 3}))
    return ref


def test_report_reference_limits_and_rollback(client: TestClient, tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    from app.api.routes import _reference

    h = _login(client)
    _planted_report_reference(tmp_path)
    files = _tree(tmp_path)
    monkeypatch.setattr(_reference, "MAX_REFERENCE_BYTES", 1000)
    for name, data, status in (("big.c3d", b"x" * 5000, 413),
                               ("bad.c3d", b"not a c3d", 400),
                               ("bad.csv", b"time,a\n1,2\n", 400),
                               ("empty.trc", b"", 400),
                               ("x.pdf", b"%PDF", 400)):
        r = client.post("/api/reports/recordings/R2/reference", headers=h,
                        files={"file": (name, data, "application/octet-stream")})
        assert r.status_code == status, f"{name}: {r.status_code} {r.text[:200]}"
        _assert_readable(r, f"report reference {name}")
    assert _tree(tmp_path) == files
    r = client.post("/api/reports/upload", headers=h,
                    files={"file": ("big.c3d", b"x" * 5000, "application/octet-stream")})
    assert r.status_code == 413
    _assert_readable(r, "report upload")
    r = client.post("/api/reports/upload", headers=h,
                    files={"file": ("bad.trc", b"garbage", "application/octet-stream")})
    _assert_readable(r, "report upload of a malformed TRC")
    assert _tree(tmp_path) == files


def test_imu_upload_limits(client: TestClient, tmp_path: Path,
                           monkeypatch: pytest.MonkeyPatch) -> None:
    from app.api.routes import imu
    from app.server.imu_analysis import ImuJob, ImuStore

    h = _login(client)
    store = ImuStore()
    store.add(ImuJob("0123456789abcdef", {"sensors": ["chest"]}, {}, "t,a\n0,1\n", "a.csv"))
    client.app.state.imu_store = store  # type: ignore[attr-defined]
    before = client.get("/api/imu/sessions/0123456789abcdef", headers=h).json()
    files = _tree(tmp_path)
    monkeypatch.setattr(imu, "MAX_FILE_BYTES", 1000)
    cases = (
        ([("files", ("chest.csv", b"x" * 5000, "text/csv"))], 413),
        ([("files", ("chest.csv", b"Packet number,Gyroscope X\n1,a\n", "text/csv"))], 400),
        ([("files", ("chest.mat", b"MATLAB garbage", "application/octet-stream"))], 400),
        ([("files", ("chest.hdf5", b"\x89HDF garbage", "application/octet-stream"))], 400),
        ([("files", ("chest.exe", b"MZ", "application/octet-stream"))], 400),
        ([("files", ("chest.csv", b"", "text/csv"))], 400),
        ([("files", (f"s{i}.csv", b"1", "text/csv")) for i in range(20)], 400),
    )
    for parts, status in cases:
        r = client.post("/api/imu/sessions", headers=h, files=parts)
        assert r.status_code == status, f"{parts[0][1][0]}: {r.status_code} {r.text[:200]}"
        _assert_readable(r, f"imu upload {parts[0][1][0]}")
    assert list(store._jobs) == ["0123456789abcdef"]  # no result added or dropped
    assert client.get("/api/imu/sessions/0123456789abcdef", headers=h).json() == before
    assert _tree(tmp_path) == files


def test_marker_id_ranges_are_bounded_before_expansion(client: TestClient) -> None:
    """"0-10000000000000" is refused, not expanded into a list of 10**13 ids (a
    MemoryError, or gigabytes of the server's memory for a smaller range)."""
    h = _login(client)
    for spec in ("0-10000000000000", "1,2,100000"):
        r = client.get("/api/calibration/markers.pdf", params={"ids": spec}, headers=h)
        _assert_readable(r, f"markers.pdf ids={spec}")
        assert "too large" in r.json()["detail"]
        r = client.post("/api/calibration/capture", json={"ids": spec}, headers=h)
        _assert_readable(r, f"capture ids={spec}")
        assert "too large" in r.json()["detail"]
    r = client.get("/api/calibration/markers.pdf", params={"ids": "1-4"}, headers=h)
    assert r.status_code == 200 and r.content.startswith(b"%PDF")


def test_anonymous_uploads_are_refused_before_the_body_is_read(
        client: TestClient, monkeypatch: pytest.MonkeyPatch) -> None:
    """An upload without a login gets 401 without the server parsing (spooling to disk)
    the file; with a login the same upload is parsed."""
    from starlette.formparsers import MultiPartParser

    parsed: list[int] = []
    original = MultiPartParser.parse

    async def spy(self: MultiPartParser) -> Any:
        parsed.append(1)
        return await original(self)

    monkeypatch.setattr(MultiPartParser, "parse", spy)
    uploads = [p for m, p, ctx in _http_routes(client)
               if isinstance(ctx.original_route, BoundedRoute)
               and ctx.original_route.body_limit > JSON_BODY_MAX]
    assert set(uploads) >= {"/api/imu/sessions", "/api/exports/{rec_id}/references",
                            "/api/reports/upload", "/api/reports/recordings/{rec_id}/reference"}
    files = {"file": ("walk.c3d", b"x" * 5000), "files": ("chest.csv", b"x" * 5000)}
    for path in uploads:
        for headers in ({}, {"Authorization": "Bearer not-a-token"}):
            r = client.post(_fill(path, "R1"), files=files, headers=headers)
            assert r.status_code == 401, f"{path}: {r.status_code}"
            _assert_readable(r, f"anonymous upload to {path}")
    assert parsed == [], "an anonymous upload was parsed"
    r = client.post("/api/reports/upload", files=files, headers=_login(client))
    assert r.status_code == 422 and parsed, r.text  # logged in: parsed and analysed


def test_stream_lists_are_bounded(client: TestClient) -> None:
    """A recording's streams are stored joined in a 120-character column (a longer value
    is an error on PostgreSQL): a list longer than the three streams is a 422."""
    h = _login(client)
    many = {"streams": ["depth"] * 1000}
    for url in ("/api/recordings", "/api/sessions/1/recordings"):
        r = client.post(url, json=many, headers=h)
        assert r.status_code == 422, f"{url}: {r.status_code} {r.text[:200]}"
        _assert_readable(r, url)
        assert "streams" in r.json()["detail"]
