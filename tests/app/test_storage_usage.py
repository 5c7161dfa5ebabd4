"""GET /api/storage answers from the usage index (no walk of every recording folder per
request) and stays right as files arrive and go: a reference uploaded, an analysis
written, a transfer ended, a recording deleted, a folder changed by hand (rescan)."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.api.routes import storage as storage_routes
from app.config import Settings
from app.main import create_app
from app.server import storage as st
from app.server.analysis import _write_json
from bench._clinic import Clinic, populate


@pytest.fixture
def clinic(tmp_path: Path) -> Iterator[tuple[TestClient, Clinic, Path]]:
    clinic = populate(tmp_path, 6, 2, n_with_files=12)
    s = Settings(data_dir=tmp_path, viewer_enabled=False, node_token="test-node-token",
                 admin_password="secret-pw", storage_check_interval_s=0)  # (no manifests)
    with TestClient(create_app(s)) as c:
        r = c.post("/api/auth/login", json={"username": "admin", "password": "secret-pw"})
        c.headers["Authorization"] = f"Bearer {r.json()['token']}"
        for _ in range(200):  # the start-up measurement, in the background
            if c.get("/api/storage?subjects=false").json()["usage_scanned_at"]:
                break
            time.sleep(0.05)
        yield c, clinic, tmp_path


def _subjects(c: TestClient, **params: Any) -> dict[str, tuple[int, int]]:
    r = c.get("/api/storage", params=params)
    assert r.status_code == 200, r.text
    return {x["code"]: (x["bytes"], x["n_recordings"]) for x in r.json()["subjects"]}


def _measured(data: Path, c: TestClient) -> dict[str, int]:
    """Every subject's bytes read from disk now (what the index must agree with)."""
    layout = st.StorageLayout(data)
    out = {}
    for s in c.get("/api/subjects", params={"limit": 500}).json():
        tree = c.get(f"/api/subjects/{s['id']}").json()
        out[s["code"]] = sum(layout.measure_bytes(r["id"]) for x in tree["sessions"]
                             for r in x["recordings"])
    return out


def _first_with_files(data: Path, c: TestClient) -> tuple[str, str, str]:
    """(subject code, recording id, node) of a recording with a part on the server."""
    for s in c.get("/api/subjects", params={"limit": 500}).json():
        tree = c.get(f"/api/subjects/{s['id']}").json()
        for x in tree["sessions"]:
            for r in x["recordings"]:
                d = data / "recordings" / r["id"]
                if d.is_dir():
                    return s["code"], r["id"], sorted(p.name for p in d.iterdir())[0]
    raise AssertionError("no recording with files")


def test_usage_follows_the_files(clinic: tuple[TestClient, Clinic, Path],
                                 monkeypatch: pytest.MonkeyPatch) -> None:
    c, cl, data = clinic
    first = _subjects(c)
    assert len(first) == 6 and sum(n for _, n in first.values()) == len(cl.recording_ids)
    assert {k: b for k, (b, _) in first.items()} == _measured(data, c)
    assert any(b > 0 for b, _ in first.values())

    # answered from the index: no recording folder is walked again
    walked: list[str] = []
    real = st.StorageLayout.measure_bytes

    def spy(self: st.StorageLayout, rec_id: str) -> int:
        walked.append(rec_id)
        return real(self, rec_id)

    monkeypatch.setattr(st.StorageLayout, "measure_bytes", spy)
    assert _subjects(c) == first
    assert walked == []

    code, rec_id, node = _first_with_files(data, c)
    # a reference file put in by hand: its folder's time says so once the kept overview
    # is older than STAMPS_MAX_AGE_S (the server's own writes are reported at once)
    refs = data / "references" / rec_id
    refs.mkdir(parents=True)
    (refs / "abc.trc").write_bytes(b"x" * 1000)
    monkeypatch.setattr(storage_routes, "STAMPS_MAX_AGE_S", 0.0)
    assert _subjects(c)[code][0] == first[code][0] + 1000
    assert walked == [rec_id]

    # an analysis written below the recording's folder: reported by the writer
    _write_json(data / "recordings" / rec_id / node / "extra.json", {"k": "v" * 500})
    assert _subjects(c)[code][0] == _measured(data, c)[code]

    # a file changed by hand deep inside: seen after a rescan, on request
    (data / "recordings" / rec_id / node / "frames.bin").write_bytes(b"\0" * 5000)
    assert _subjects(c)[code][0] != _measured(data, c)[code]
    after = _subjects(c, rescan="true")
    assert {k: b for k, (b, _) in after.items()} == _measured(data, c)

    # a recording deleted: its bytes and count leave the subject
    before = after[code]
    gone = st.StorageLayout(data).measure_bytes(rec_id)
    r = c.post(f"/api/storage/recordings/{rec_id}/delete", json={"confirm": code})
    assert r.status_code == 200, r.text
    assert _subjects(c)[code] == (before[0] - gone, before[1] - 1)
    assert {k: b for k, (b, _) in _subjects(c).items()} == _measured(data, c)


def test_a_transfer_that_ends_is_measured_again(tmp_path: Path) -> None:
    rec_dir = tmp_path / "recordings" / "R1"
    (rec_dir / "S1").mkdir(parents=True)
    idx = st.usage_index(tmp_path)
    assert idx.recording_bytes("R1") == 0
    (rec_dir / "S1" / "frames.bin").write_bytes(b"\0" * 300)  # deep: the stamp stays
    assert idx.recording_bytes("R1") == 0
    st.note_changed(rec_dir / "S1")  # what the transfer manager says when a part ends
    assert idx.recording_bytes("R1") == 300
    st.StorageLayout(tmp_path).delete_recording("R1")
    assert idx.many(["R1", "R2"]) == {"R1": 0, "R2": 0}


def test_files_that_vanish_while_counted_count_nothing(tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """A transfer renames its temporary files into place while the storage pages poll a
    recording's size: a file listed and then gone before it is measured counts 0 (it
    answered the Record page's poll with a 500), and so does a folder gone meanwhile.
    Links are not followed (a size is the data folder's own)."""
    rec = tmp_path / "rec"
    (rec / "S1").mkdir(parents=True)
    (rec / "S1" / "frames.bin").write_bytes(b"x" * 1000)
    (rec / "S1" / "chunk.tmp").write_bytes(b"y" * 500)
    (rec / "S2").mkdir()
    (rec / "S2" / "frames.bin").write_bytes(b"z" * 300)
    outside = tmp_path / "outside.bin"
    outside.write_bytes(b"o" * 10_000)
    (rec / "S1" / "link.bin").symlink_to(outside)
    assert st.dir_bytes(rec) == 1800
    real_walk = st.os.walk

    def walk_then_vanish(top: Any, *a: Any, **k: Any) -> Iterator[Any]:
        for base, dirs, files in real_walk(top, *a, **k):
            # listed, then renamed into place and removed before being measured
            for name in files:
                if name == "chunk.tmp":
                    (Path(base) / name).unlink()
            yield base, dirs, files

    monkeypatch.setattr(st.os, "walk", walk_then_vanish)
    assert st.dir_bytes(rec) == 1300
    assert st.dir_bytes(tmp_path / "no-such-folder") == 0
