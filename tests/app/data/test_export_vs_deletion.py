"""A subject's export being downloaded and a deletion of its data: the deletion waits
its turn (409) instead of cutting the download short, and an export is refused while
a deletion of the subject runs. Each side is held mid-way on purpose (events, no
timing)."""

from __future__ import annotations

import contextlib
import io
import threading
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import anyio
import pytest
from fastapi.testclient import TestClient

from app.api.routes import _data
from app.api.routes import subjects as subjects_route
from app.config import Settings
from app.main import create_app
from tests.app.data.walk_recording import walk_subject

WAIT_S = 60.0  # only a bound for a broken test; nothing is timed


@pytest.fixture
def client(admin_client: TestClient) -> TestClient:
    return admin_client


def test_a_deletion_waits_for_the_export_being_downloaded(
        client: TestClient, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    ids = walk_subject(client, tmp_path)
    sid, sess = ids["subject_id"], ids["session_id"]
    reached, go = threading.Event(), threading.Event()
    render = subjects_route._report_pdf

    def held_report(*a: Any) -> bytes | None:
        # the recordings' files are already in the archive: the download is under way
        reached.set()
        assert go.wait(WAIT_S)
        return render(*a)

    monkeypatch.setattr(subjects_route, "_report_pdf", held_report)
    with ThreadPoolExecutor(1) as pool:
        download = pool.submit(client.get, f"/api/subjects/{sid}/export")
        assert reached.wait(WAIT_S)
        for path, confirm in ((f"/api/subjects/{sid}/delete", "A1"),
                              (f"/api/sessions/{sess}/delete", "A1"),
                              ("/api/storage/recordings/R1/delete", "A1")):
            r = client.post(path, json={"confirm": confirm})
            assert r.status_code == 409, (path, r.status_code, r.text)
            assert "export is being downloaded" in r.json()["detail"]
        assert (tmp_path / "recordings" / "R1" / "S1" / "frames.bin").is_file()
        go.set()
        r = download.result(WAIT_S)
    assert r.status_code == 200
    z = zipfile.ZipFile(io.BytesIO(r.content))
    assert z.testzip() is None
    names = z.namelist()
    assert "recordings/R1/S1/frames.bin" in names and "export-notes.json" in names
    assert any(n.startswith("reports/") for n in names)
    # the download has ended: the deletion goes through
    r = client.post(f"/api/subjects/{sid}/delete", json={"confirm": "A1"})
    assert r.status_code == 200, r.text
    assert not (tmp_path / "recordings" / "R1").exists()
    assert client.get(f"/api/subjects/{sid}/export").status_code == 404


def test_no_export_starts_while_the_subject_is_being_deleted(
        client: TestClient, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    ids = walk_subject(client, tmp_path)
    sid = ids["subject_id"]
    reached, go = threading.Event(), threading.Event()
    remove = _data._remove_files

    def held_removal(*a: Any) -> None:
        reached.set()  # rows committed, files not yet removed
        assert go.wait(WAIT_S)
        remove(*a)

    monkeypatch.setattr(_data, "_remove_files", held_removal)
    with ThreadPoolExecutor(1) as pool:
        deletion = pool.submit(client.post, f"/api/subjects/{sid}/delete",
                               json={"confirm": "A1"})
        assert reached.wait(WAIT_S)
        r = client.get(f"/api/subjects/{sid}/export")
        assert r.status_code == 409 and "being deleted" in r.json()["detail"], r.text
        go.set()
        assert deletion.result(WAIT_S).status_code == 200
    assert client.get(f"/api/subjects/{sid}/export").status_code == 404


@pytest.mark.parametrize("spec", ["2.4", "2.0"])
def test_a_download_cancelled_midway_frees_the_subject(
        client: TestClient, tmp_path: Path, spec: str) -> None:
    """A client that goes away mid-download (browser closed) releases the subject: the
    server's send fails (ASGI 2.4) or it hears the disconnect (older ASGI servers)."""
    ids = walk_subject(client, tmp_path)
    sid = ids["subject_id"]
    token = client.headers["Authorization"].encode()
    sent: list[dict[str, Any]] = []
    gone = anyio.Event()

    asked: list[bool] = []

    async def receive() -> dict[str, Any]:
        if not asked:
            asked.append(True)
            return {"type": "http.request", "body": b"", "more_body": False}
        await gone.wait()
        return {"type": "http.disconnect"}

    async def send(msg: dict[str, Any]) -> None:
        body = msg["type"] == "http.response.body" and msg.get("body")
        if body and any(m["type"] == "http.response.body" for m in sent):
            gone.set()  # the client leaves after the first piece
            if spec == "2.4":
                raise OSError("connection reset by peer")
            await anyio.sleep_forever()  # the server notices through receive()
        sent.append(msg)

    scope = {"type": "http", "asgi": {"version": "3.0", "spec_version": spec},
             "http_version": "1.1", "method": "GET", "scheme": "http",
             "path": f"/api/subjects/{sid}/export", "raw_path": b"", "query_string": b"",
             "root_path": "", "headers": [(b"host", b"t"), (b"authorization", token)],
             "client": ("127.0.0.1", 5000), "server": ("t", 80)}

    async def download() -> None:
        with contextlib.suppress(Exception):
            await client.app(scope, receive, send)  # type: ignore[arg-type]

    client.portal.call(download)  # type: ignore[union-attr]
    assert sent[0]["status"] == 200 and gone.is_set()
    assert not client.app.state.exports.exporting  # type: ignore[attr-defined]
    r = client.post(f"/api/subjects/{sid}/delete", json={"confirm": "A1"})
    assert r.status_code == 200, r.text


def test_two_apps_in_one_process_keep_their_own_guard(client: TestClient,
                                                      tmp_path: Path) -> None:
    """The guard lives on each app (``app.state.exports``): an export held by one app
    refuses that app's deletion only, not another app's of a subject with the same id."""
    sid = walk_subject(client, tmp_path)["subject_id"]
    other_dir = tmp_path / "other"
    s = Settings(data_dir=other_dir, viewer_enabled=False, node_token="test-node-token",
                 admin_password="secret-pw")
    with TestClient(create_app(s), raise_server_exceptions=False) as other:
        r = other.post("/api/auth/login", json={"username": "admin", "password": "secret-pw"})
        other.headers["Authorization"] = f"Bearer {r.json()['token']}"
        other_sid = walk_subject(other, other_dir)["subject_id"]
        assert other_sid == sid  # the same id in two databases
        guard = client.app.state.exports  # type: ignore[attr-defined]
        assert guard is not other.app.state.exports  # type: ignore[attr-defined]
        release = guard.start_export(sid)  # an export of the first app under way
        try:
            r = client.post(f"/api/subjects/{sid}/delete", json={"confirm": "A1"})
            assert r.status_code == 409, r.text
            r = other.post(f"/api/subjects/{other_sid}/delete", json={"confirm": "A1"})
            assert r.status_code == 200, r.text
        finally:
            release()
    r = client.post(f"/api/subjects/{sid}/delete", json={"confirm": "A1"})
    assert r.status_code == 200, r.text
