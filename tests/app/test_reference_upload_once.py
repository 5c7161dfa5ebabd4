"""A reference recording attached on the Subjects page or the Reports page was parsed
twice: once to check it (``app.server.storage.read_reference``) and again, from the file,
by the gait check (``app.server.analysis.reference_steps``) — ≈ 2 s more for a 200 MB C3D.
The check hands what was read to the analysis now: one parse per upload, the same steps.

A reference too large for the server was refused in two ways: a request whose declared
``Content-Length`` (or whose streamed body) is over the route's body limit got the
general "the request is larger than this route accepts (200 MB); send a smaller file or
fewer values", a file over the per-file limit "'x' is larger than 200 MB, the largest
file the server takes: …". Both are one message now, naming the file when it is known
(:func:`app.api.routes._reference.too_large`)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from tests.app.mocap_files import walk_skeleton_c3d, walk_skeleton_csv, walk_trc
from tests.app.test_upload_errors import INTERNAL, _filed_recording

URLS = ("/api/exports/R1/references", "/api/reports/recordings/R1/reference")
#: every route that takes a reference-sized file ("Analyse a file" takes the same files)
ALL_URLS = (*URLS, "/api/reports/upload")


def _files(tmp_path: Path) -> dict[str, bytes]:
    return {"walk.c3d": walk_skeleton_c3d()[0], "walk.csv": walk_skeleton_csv(),
            "walk.trc": walk_trc(tmp_path / "w.trc").read_bytes()}


def _count_parses(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Every parse of a C3D, TRC or skeleton CSV file from now on, by whichever module
    calls its reader (the readers are imported by name in app.server.storage and inside
    engine.mocap.load_feet)."""
    import engine.io.c3d as c3d
    import engine.io.csv as csv
    import engine.io.trc as trc
    from app.server import storage

    parsed: list[str] = []

    def spy(real: Callable[..., Any]) -> Callable[..., Any]:
        def read(path: Any, *a: Any, **k: Any) -> Any:
            parsed.append(Path(path).name)
            return real(path, *a, **k)
        return read

    for module, name in ((c3d, "read_c3d"), (trc, "read_trc"), (csv, "read_skeleton_csv")):
        real = getattr(module, name)
        monkeypatch.setattr(module, name, spy(real))
        monkeypatch.setattr(storage, name, spy(real))
    return parsed


@pytest.mark.parametrize("url", URLS)
def test_an_upload_is_parsed_once(admin_client: TestClient, tmp_path: Path,
                                  monkeypatch: pytest.MonkeyPatch, url: str) -> None:
    _filed_recording(admin_client, tmp_path, "R1")
    files = _files(tmp_path)
    parsed = _count_parses(monkeypatch)
    for name, data in files.items():
        parsed.clear()
        r = admin_client.post(url, files={"file": (name, data, "application/octet-stream")})
        assert r.status_code == 201, f"{name}: {r.text}"
        assert len(parsed) == 1, f"{name} parsed {len(parsed)} times: {parsed}"


def test_the_steps_of_what_was_read_are_the_steps_of_the_file(tmp_path: Path) -> None:
    """``reference_steps(path, data=parse_reference(path))`` finds the steps
    ``reference_steps(path)`` finds, for each format, and leaves ``data`` as read (a
    skeleton CSV's units are scaled in a copy)."""
    import numpy as np

    from app.server import analysis as an
    from app.server import storage

    for name, data in _files(tmp_path).items():
        path = tmp_path / name
        path.write_bytes(data)
        ext = path.suffix[1:]
        read = storage.parse_reference(path, ext)
        before = read.positions.copy()
        assert an.reference_steps(path, data=read) == an.reference_steps(path), name
        assert np.array_equal(read.positions, before, equal_nan=True), name
        m = storage.read_reference(path, ext)
        assert m.labels == storage.reference_markers(read).labels and len(m) == len(read)


# ------------------------------------------------------------------ one too-large message

def _limit(monkeypatch: pytest.MonkeyPatch, client: TestClient, n_bytes: int) -> None:
    """Make the reference limit ``n_bytes`` for the file and, with the multipart
    overhead, for the request body of every route that takes a reference."""
    from fastapi.routing import iter_route_contexts

    from app.api.limits import BoundedRoute
    from app.api.routes import _reference

    usual = _reference.MAX_REFERENCE_BYTES + _reference.UPLOAD_OVERHEAD
    monkeypatch.setattr(_reference, "MAX_REFERENCE_BYTES", n_bytes)
    n = 0
    for r in iter_route_contexts(client.app.routes):  # type: ignore[attr-defined]
        route = r.original_route
        if (isinstance(route, BoundedRoute) and "POST" in (r.methods or ())
                and r.path in ("/api/exports/{rec_id}/references",
                               "/api/reports/recordings/{rec_id}/reference",
                               "/api/reports/upload")):
            assert route.body_limit == usual, (r.path, route.body_limit)
            monkeypatch.setattr(route, "body_limit", n_bytes + _reference.UPLOAD_OVERHEAD)
            n += 1
    assert n == 3, n


def _multipart(name: str, size: int) -> tuple[Iterator[bytes], dict[str, str]]:
    """A multipart body carrying a file ``name`` of ``size`` bytes, streamed (no
    Content-Length), and its headers."""
    def body() -> Iterator[bytes]:
        yield (f'--x\r\nContent-Disposition: form-data; name="file"; filename="{name}"'
               "\r\nContent-Type: application/octet-stream\r\n\r\n").encode()
        for _ in range(size // 65536):
            yield b"\0" * 65536
        yield b"\0" * (size % 65536) + b"\r\n--x--\r\n"
    return body(), {"Content-Type": "multipart/form-data; boundary=x"}


WHAT_TO_DO = ("is larger than 3 MB, the largest file the server takes: export only the walk "
              "(without analog channels) from the motion-capture software and upload it")


def _nothing_attached(c: TestClient) -> None:
    assert c.get("/api/exports/R1/references").json() == []
    assert c.get("/api/reports/recordings/R1/reference").json()["attached"] is False


def test_a_too_large_reference_gets_one_message_whatever_check_catches_it(
        admin_client: TestClient, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    c = admin_client
    _filed_recording(c, tmp_path, "R1")
    _limit(monkeypatch, c, 3 * 2**20)
    said: dict[str, set[tuple[int, str]]] = {}
    for url in ALL_URLS:
        # the file over the file limit, the request within the body limit: the file named
        r = c.post(url, files={"file": ("long session.c3d", b"\0" * (3 * 2**20 + 1),
                                        "application/octet-stream")})
        said.setdefault("file", set()).add((r.status_code, r.json()["detail"]))
        # a declared Content-Length over the body limit: refused before the body is read
        r = c.post(url, content=b"--x--\r\n",
                   headers={"Content-Type": "multipart/form-data; boundary=x",
                            "Content-Length": str(4 * 2**20)})
        said.setdefault("declared", set()).add((r.status_code, r.json()["detail"]))
        # a streamed body (no Content-Length) over the body limit: refused while read
        body, headers = _multipart("long session.c3d", 4 * 2**20)
        r = c.post(url, content=body, headers=headers)
        said.setdefault("streamed", set()).add((r.status_code, r.json()["detail"]))
    for how, got in said.items():
        assert len(got) == 1, (how, got)  # the same on every route
    (code, file_words), = said["file"]
    assert code == 413
    assert file_words == f"'long session.c3d' {WHAT_TO_DO}", file_words
    for how in ("declared", "streamed"):
        (code, words), = said[how]
        assert code == 413, (how, code)
        # the file's name is not known before the body is read: the same words
        assert words == f"The file {WHAT_TO_DO}", (how, words)
        assert not INTERNAL.search(words) and "request" not in words, words
    _nothing_attached(c)


def test_the_limit_is_said_in_whole_megabytes_or_kilobytes() -> None:
    from app.api.limits import size_words

    assert size_words(200 * 2**20) == "200 MB"
    assert size_words(200 * 2**20 + 64 * 1024) == "200 MB"
    assert size_words(3 * 2**20) == "3 MB"
    assert size_words(1000) == "1 KB"
    assert size_words(4096) == "4 KB"
    # a size said to be over a limit is rounded up, never down to the limit itself
    assert size_words(256 * 2**20 + 300 * 1024, round_up=True) == "257 MB"
    assert size_words(256 * 2**20, round_up=True) == "256 MB"
    assert size_words(4097, round_up=True) == "5 KB"
