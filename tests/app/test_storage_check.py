"""The periodic check of settled recordings: a server copy removed or cut by hand is shown
as missing (in words for a clinician) and audited; nothing else changes; a copy put back
is complete again."""

from __future__ import annotations

import json
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import select
from sqlalchemy.orm import selectinload

from app.config import Settings
from app.db import data as m
from app.db.base import make_engine, make_session_factory
from app.db.models import AuditEvent
from app.server.datasync import SERVER_COPY_MISSING, DataSync, server_copy_fault
from app.server.hub import Hub
from app.server.storage import StorageLayout


@pytest.fixture
def sync(tmp_path: Path) -> Iterator[DataSync]:
    from bench._clinic import populate

    populate(tmp_path, 4, 2, n_with_files=8)  # every recording's complete parts on disk
    for part in (tmp_path / "recordings").glob("*/*"):  # as a transfer leaves them
        files = [{"name": f.name, "size": f.stat().st_size} for f in sorted(part.iterdir())]
        (part / "manifest.json").write_text(json.dumps({"files": files}))
    settings = Settings(data_dir=tmp_path, viewer_enabled=False)
    engine = make_engine(settings.db_url)
    ds = DataSync(Hub(settings), make_session_factory(engine), StorageLayout(tmp_path),
                  check_interval_s=1.0)
    while ds.sweeping != 0:
        ds.step()
    try:
        yield ds
    finally:
        engine.dispose()


def _rows(ds: DataSync) -> dict[str, Any]:
    with ds.db_sessions() as db:
        return {r.id: (r.state, r.reason, r.t_start, r.t_stop,
                       [(p.node_id, p.state, p.reason, p.bytes_done) for p in r.parts])
                for r in db.scalars(select(m.Recording).options(
                    selectinload(m.Recording.parts)))}


def _audit(ds: DataSync) -> list[tuple[str, str, str]]:
    with ds.db_sessions() as db:
        return [(a.username, a.target, a.detail) for a in db.scalars(
            select(AuditEvent).where(AuditEvent.action == "storage_check"))]


def _round(ds: DataSync) -> None:
    """One round of the periodic check, over the passes it is spread on."""
    ds.begin_check(ds._settled_ids())
    assert not ds._check_due()  # a round under way
    passes = 0
    while ds._check_queue:
        ds.step()
        passes += 1
    assert passes >= 2  # spread (1 s of 0.5 s passes), not all at once


def test_a_settled_copy_removed_by_hand_is_shown_missing(sync: DataSync, tmp_path: Path) -> None:
    before = _rows(sync)
    complete = sorted(k for k, v in before.items() if v[0] == "complete")
    assert len(complete) >= 3
    assert sync._check_due()  # the first round begins once the start-up sweep is done
    _round(sync)
    assert sync.found_damaged == [] and sync.checked == len(complete)
    assert _rows(sync) == before

    gone, cut = complete[0], complete[1]
    shutil.rmtree(tmp_path / "recordings" / gone)
    node = sorted(p.name for p in (tmp_path / "recordings" / cut).iterdir())[0]
    (tmp_path / "recordings" / cut / node / "frames.bin").write_bytes(b"\0" * 10)
    _round(sync)
    assert sorted(sync.found_damaged) == sorted([gone, cut])
    after = _rows(sync)
    # only those two changed, and only their state and reasons
    assert {k: v for k, v in after.items() if k not in (gone, cut)} == \
        {k: v for k, v in before.items() if k not in (gone, cut)}
    state, reason, t0, t1, parts = after[gone]
    assert state == "incomplete" and reason.startswith(SERVER_COPY_MISSING)
    assert "its folder is gone" in reason and (t0, t1) == before[gone][2:4]
    assert all(p[1] == "incomplete" and p[2].startswith(SERVER_COPY_MISSING) for p in parts)
    assert [p[3] for p in parts] == [p[3] for p in before[gone][4]]
    assert f"{node}: frames.bin has 10 bytes instead of 64" in after[cut][1]
    assert [p[1] for p in after[cut][4]] == [
        "incomplete" if p[0] == node else p[1] for p in before[cut][4]]
    audit = _audit(sync)
    assert sorted(t for _, t, _ in audit) == sorted([f"recording {gone}", f"recording {cut}"])
    assert all(u == "(server)" and d.startswith(SERVER_COPY_MISSING) for u, _, d in audit)

    # checked again: nothing new (no second audit entry)
    _round(sync)
    assert len(_audit(sync)) == 2 and _rows(sync) == after

    # the copy restored from a backup: complete again
    (tmp_path / "recordings" / cut / node / "frames.bin").write_bytes(b"\0" * 64)
    _round(sync)
    assert _rows(sync)[cut] == before[cut]
    assert _rows(sync)[gone] == after[gone]


def test_no_check_when_disabled_and_faults_in_words(sync: DataSync, tmp_path: Path) -> None:
    sync.check_interval_s = 0
    assert not sync._check_due()
    part = next((tmp_path / "recordings").glob("*/*"))
    assert server_copy_fault(part) is None
    (part / "manifest.json").write_text("{")
    assert server_copy_fault(part) == "its manifest.json is unreadable"
    (part / "manifest.json").unlink()
    assert server_copy_fault(part) == "its manifest.json is gone"
    assert server_copy_fault(part / "nope") == "its folder is gone"
