"""A data sync pass examines only the recordings that can still change, not the
thousands a clinic keeps settled (complete, or incomplete for good)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import select

from app.config import Settings
from app.db import data as m
from app.db.base import make_engine, make_session_factory
from app.nodes.protocol import PartInfo
from app.server.datasync import DataSync
from app.server.hub import Hub
from app.server.storage import StorageLayout
from bench._clinic import populate


@pytest.fixture(params=[40, 400], ids=["small", "large"])
def clinic(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[tuple[DataSync, Any]]:
    """A data sync over a clinic of 40 or 400 subjects (2 recordings each, ~5 % of them
    incomplete for good, ~1 % with parts on nodes that are not connected)."""
    populate(tmp_path, request.param, 2)
    settings = Settings(data_dir=tmp_path, viewer_enabled=False)
    engine = make_engine(settings.db_url)
    sessions = make_session_factory(engine)
    sync = DataSync(Hub(settings), sessions, StorageLayout(tmp_path))
    try:
        yield sync, sessions
    finally:
        engine.dispose()


def _not_complete(sync: DataSync, sessions: Any) -> list[str]:
    with sessions() as db:
        return sorted(db.scalars(select(m.Recording.id).where(
            m.Recording.state != "complete")))


def _sweep(sync: DataSync) -> int:
    """Run the passes of the start-up sweep; the recordings they examined."""
    n = 0
    while sync.sweeping != 0:
        sync.step()
        n += sync.examined_last
    return n


def test_a_pass_examines_what_can_change_not_the_settled(
        clinic: tuple[DataSync, Any], monkeypatch: pytest.MonkeyPatch) -> None:
    sync, sessions = clinic
    live = sync.hub.recordings.recordings
    # the first passes look at everything not complete once
    assert len(live) > _sweep(sync) == len(_not_complete(sync, sessions)) > 0
    sync.step()
    assert sync.examined_last == 0  # all settled: nothing to do
    unsettled = _not_complete(sync, sessions)
    assert unsettled  # the clinic keeps incomplete ones (what used to be revisited)

    # one recording in transfer: examined (and its row written) every pass, alone
    rec = live[unsettled[0]]
    node, part = next(iter(rec.parts.items()))
    part.state, part.transfer_progress = "transferring", 0.25
    monkeypatch.setattr(sync.hub.transfers, "running", lambda: [rec.id])
    monkeypatch.setattr(sync.hub.transfers, "running_parts",
                        lambda r: {node} if r == rec.id else set())
    for _ in range(3):
        sync.step()
        assert sync.examined_last == 1
    with sessions() as db:
        assert db.get(m.Recording, rec.id).state == "transferring"  # type: ignore[union-attr]

    # the transfer ends: looked at once more (its outcome written), then settled
    part.state, part.transfer_progress, part.reason = "on_node", None, "transfer failed (x)"
    monkeypatch.setattr(sync.hub.transfers, "running", lambda: [])
    monkeypatch.setattr(sync.hub.transfers, "running_parts", lambda r: set())
    sync.step()
    assert sync.examined_last == 1
    with sessions() as db:
        row = db.get(m.Recording, rec.id)
        assert row is not None and row.state == "incomplete" and "transfer failed" in (
            row.reason or "")
    sync.step()
    assert sync.examined_last == 0


def test_a_change_by_a_node_is_seen_by_the_next_pass(clinic: tuple[DataSync, Any]) -> None:
    sync, sessions = clinic
    _sweep(sync)
    sync.step()
    assert sync.examined_last == 0
    done = [r for r in sync.hub.recordings.recordings.values()
            if r.id not in _not_complete(sync, sessions)]
    # a node reports a part of a settled incomplete recording: examined (once)
    rec_id = _not_complete(sync, sessions)[-1]
    rec = sync.hub.recordings.recordings[rec_id]
    node = next(n for n, p in rec.parts.items() if not p.on_server)
    sync.hub.recordings.on_part(node, PartInfo(rec_id=rec_id, state="incomplete",
                                               reason="disk full on the node", n_frames=3,
                                               bytes=10), save=False)
    sync.step()
    assert sync.examined_last == 1
    with sessions() as db:
        row = db.get(m.Recording, rec_id)
        assert row is not None and "disk full on the node" in (row.reason or "")
    sync.step()
    assert sync.examined_last == 0
    assert done  # complete recordings exist and were never examined after the first pass
    # a recording put (back) into the live list is examined, every time it is
    for _ in range(2):
        sync.hub.recordings.recordings[rec_id] = rec
        sync.step()
        assert sync.examined_last == 1


def test_a_row_whose_recording_the_server_lost_is_marked(clinic: tuple[DataSync, Any]) -> None:
    sync, sessions = clinic
    _sweep(sync)
    rec_id = _not_complete(sync, sessions)[0]
    with sessions() as db:
        row = db.get(m.Recording, rec_id)
        assert row is not None
        row.state = "on_nodes"
        db.commit()
    del sync.hub.recordings.recordings[rec_id]  # recordings.json lost it
    sync.step()
    with sessions() as db:
        row = db.get(m.Recording, rec_id)
        assert row is not None and row.state == "incomplete"
        assert "lost track" in (row.reason or "")


def test_the_start_up_sweep_is_spread_over_passes(clinic: tuple[DataSync, Any],
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """Every recording not complete is looked at once after the start, a few per pass
    (one pass over a clinic's thousands held the event loop for seconds)."""
    import app.server.datasync as ds

    sync, sessions = clinic
    monkeypatch.setattr(ds, "SWEEP_CHUNK", 5)
    want = len(_not_complete(sync, sessions))
    assert sync.sweeping is None  # not read before the first pass (or start())
    seen = []
    while sync.sweeping != 0:
        sync.step()
        assert sync.examined_last <= 5
        seen.append(sync.examined_last)
    assert sum(seen) == want and len(seen) == -(-want // 5)
    sync.step()
    assert sync.examined_last == 0


def test_start_reads_the_sweep_in_a_worker_thread(clinic: tuple[DataSync, Any]) -> None:
    import asyncio
    import threading

    sync, _ = clinic
    where: list[str] = []
    read = sync._sweep_ids

    def spy() -> list[str]:
        where.append(threading.current_thread().name)
        return read()

    sync._sweep_ids = spy  # type: ignore[method-assign]

    async def run() -> None:
        sync.start(interval_s=0.01)
        for _ in range(500):
            await asyncio.sleep(0.01)
            if sync.sweeping == 0:
                break
        await sync.stop()

    asyncio.run(run())
    assert where and where[0] != threading.main_thread().name
    assert sync.sweeping == 0
