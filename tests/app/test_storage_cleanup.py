"""Leftovers of uploads and writes cut short are removed when the server starts (not only
by the next upload to that recording), never an upload in progress or a transfer's
files; a reference import's file is in place before its row commits."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.config import Settings
from app.db import data as m
from app.main import create_app
from app.server.cleanup import STALE_S, clean_stale

OLD = time.time() - STALE_S - 3600


def _put(path: Path, old: bool, data: bytes = b"x") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    if data == b"/":
        path.mkdir()
        (path / "inside").write_bytes(b"x")
    else:
        path.write_bytes(data)
    if old:
        os.utime(path, (OLD, OLD))
    return path


def _plant(data: Path) -> tuple[list[Path], list[Path]]:
    """(leftovers that must go, files that must stay)."""
    refs, recs = data / "references" / "R1", data / "recordings" / "R1"
    gone = [_put(refs / ".0123456789abcdef.csv.upload.tmp", True),
            _put(refs / "fedcba9876543210.trc", True),  # no row: its commit never came
            _put(recs / ".reference-upload-abc.tmp", True, b"/"),
            _put(recs / ".reference-upload-deleted-1234.tmp", False, b"/"),  # deleted
            _put(recs / "analysis" / ".walk.json.77.ab12.tmp", True),
            _put(recs / ".sensors.json.77.cd34.tmp", True)]
    keep = [_put(refs / ".1111111111111111.csv.upload.tmp", False),  # in progress
            _put(refs / "abcdefabcdefabcd.csv", True),  # its row exists
            _put(refs / "2222222222222222.c3d", False),  # its row may be on its way
            _put(recs / ".reference-upload-new.tmp", False, b"/"),
            _put(recs / "analysis" / "walk.json", True),
            _put(recs / "sensors.json", True),
            _put(recs / "S1" / ".incoming" / "frames.bin.tmp", True),  # a transfer's
            _put(recs / "S1" / "manifest.json.tmp", True),
            _put(recs / ".S2.tmp" / "meta.json", True)]  # a part (node ".S2.tmp")
    return gone, keep


def test_stale_leftovers_go_and_nothing_else(tmp_path: Path) -> None:
    gone, keep = _plant(tmp_path)
    removed = clean_stale(tmp_path, {("R1", "abcdefabcdefabcd.csv")})
    assert sorted(removed) == sorted(gone)
    assert not any(p.exists() for p in gone)
    assert all(p.exists() for p in keep)
    assert clean_stale(tmp_path, {("R1", "abcdefabcdefabcd.csv")}) == []


def test_reference_files_without_rows_stay_when_rows_are_not_known(tmp_path: Path) -> None:
    _plant(tmp_path)
    clean_stale(tmp_path, None)
    assert (tmp_path / "references" / "R1" / "fedcba9876543210.trc").exists()


def test_the_server_cleans_up_when_it_starts(tmp_path: Path) -> None:
    gone, keep = _plant(tmp_path)
    s = Settings(data_dir=tmp_path, viewer_enabled=False, node_token="test-node-token",
                 admin_password="secret-pw")
    with TestClient(create_app(s)) as c:
        for _ in range(200):
            if not any(p.exists() for p in gone):
                break
            time.sleep(0.05)
        c.get("/healthz")
    assert not any(p.exists() for p in gone)
    # the row of abcdef… does not exist in this database: an orphan (old) too
    assert all(p.exists() for p in keep if p.name != "abcdefabcdefabcd.csv")


def _skeleton_csv() -> bytes:
    """A skeleton CSV of a walk: a reference the Subjects page accepts."""
    from tests.app.mocap_files import walk_skeleton_csv

    return walk_skeleton_csv()


def test_a_reference_import_lands_before_its_row(admin_client: TestClient, tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """A backup between the row's commit and the rename held the row without its file."""
    c = admin_client
    pid = c.post("/api/projects", json={"name": "p"}).json()["id"]
    sid = c.post("/api/subjects", json={"project_id": pid, "code": "P1"}).json()["id"]
    se = c.post("/api/sessions", json={"subject_id": sid}).json()["id"]
    with c.app.state.db_sessions() as db:  # type: ignore[attr-defined]
        db.add(m.Recording(id="R1", session_id=se, state="complete"))
        db.commit()
    folder = tmp_path / "references" / "R1"
    at_insert: list[list[str]] = []

    def seen(_mapper: object, _conn: object, target: m.ReferenceImport) -> None:
        at_insert.append(sorted(p.name for p in folder.iterdir()))
        assert target.stored_name in at_insert[-1]

    sa.event.listen(m.ReferenceImport, "after_insert", seen)
    try:
        r = c.post("/api/exports/R1/references",
                   files={"file": ("walk.csv", _skeleton_csv(), "text/csv")})
    finally:
        sa.event.remove(m.ReferenceImport, "after_insert", seen)
    assert r.status_code == 201, r.text
    assert len(at_insert) == 1 and len(at_insert[0]) == 1  # the file, no .tmp beside it
    assert not at_insert[0][0].endswith(".tmp")

    # a commit that fails takes the placed file with it
    from sqlalchemy.orm import Session

    def fail(self: Session) -> None:
        raise sa.exc.OperationalError("COMMIT", {}, Exception("disk I/O error"))

    before = sorted(p.name for p in folder.iterdir())
    with monkeypatch.context() as mp:
        mp.setattr(Session, "commit", fail)
        r = c.post("/api/exports/R1/references",
                   files={"file": ("walk2.csv", _skeleton_csv(), "text/csv")})
    assert r.status_code >= 400
    assert sorted(p.name for p in folder.iterdir()) == before
