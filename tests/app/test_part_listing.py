"""A node's listing of the parts it holds, on connecting: complete however many there are
(a node offline through a long clinic day), in control messages the server accepts."""

from __future__ import annotations

import asyncio
import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from app.config import Settings
from app.main import create_app
from app.nodes.agent import NodeAgent
from app.nodes.protocol import (
    PART_LIST_BYTES,
    Hello,
    PartInfo,
    PartList,
    dump,
    parse_node_message,
    part_batches,
)
from app.nodes.store import NodeStore
from tests.app.test_agent import _Scripted  # a sensor that sends nothing
from tests.app.test_hub_connections import free_port, serving

N_PARTS = 260  # more than the 200 a hello used to carry
NODE_TOKEN = "test-node-token"
WAIT_S = 60.0  # only a bound for a broken test; nothing is timed


def _part(k: int, reason: str | None = None) -> PartInfo:
    return PartInfo(rec_id=f"R{k:04d}", state="on_node", n_frames=900 + k, t_first=1e9 + k,
                    t_last=1e9 + k + 30.0, bytes=123_456_789, reason=reason)


def test_batches_keep_every_part_in_order_and_each_fits_a_control_message() -> None:
    parts = [_part(k, "x" * (k % 7) * 300 or None) for k in range(N_PARTS)]
    batches = part_batches(parts)
    assert len(batches) > 1
    assert [p for b in batches for p in b] == parts
    default_limit = Settings().max_control_bytes
    for i, b in enumerate(batches):
        msg = dump(Hello(node_id="S1", token=NODE_TOKEN, parts=b)) if i == 0 \
            else dump(PartList(parts=b))
        assert len(msg) <= default_limit
        assert len("[" + ",".join(p.model_dump_json() for p in b) + "]") <= PART_LIST_BYTES
        assert parse_node_message(msg, default_limit).parts == b
    assert part_batches([]) == []
    # a part alone is never split, even one larger than the budget
    assert part_batches(parts[:3], max_bytes=10) == [[p] for p in parts[:3]]


@pytest.fixture
def server(tmp_path: Path) -> Iterator[tuple[Settings, object]]:
    """A real server on a loopback port, that knows N_PARTS stopped recordings whose part
    on node S1 it last saw recording (the node was offline when they ended)."""
    data = tmp_path / "server"
    data.mkdir()
    now = time.time()
    recs = [{"id": f"R{k:04d}", "t_start": now - 3600 + k, "t_stop": now - 3590 + k,
             "parts": {"S1": {"node_id": "S1", "state": "recording"}}}
            for k in range(N_PARTS)]
    (data / "recordings.json").write_text(json.dumps(recs))
    port = free_port()
    settings = Settings(data_dir=data, viewer_enabled=False, node_token=NODE_TOKEN,
                        admin_password="secret-pw", port=port)
    app = create_app(settings)
    with serving(app, port):
        yield settings, app


def test_a_node_holding_more_parts_than_one_message_lists_them_all(
        server: tuple[Settings, object], tmp_path: Path) -> None:
    settings, app = server
    node_dir = tmp_path / "node"
    store = NodeStore(node_dir / "recordings")
    for k in range(N_PARTS):
        store.create_part(f"R{k:04d}").close("on_node")
    assert len(part_batches(store.parts())) > 1  # the listing needs several messages
    agent = NodeAgent("S1", _Scripted(), f"ws://127.0.0.1:{settings.port}/ws/node", NODE_TOKEN,
                      node_dir)
    # the recording list is rewritten whole by a save (about a second at a clinic's
    # 30 000 recordings, in the event loop): once per listing message, not once per part
    live = app.state.hub.recordings  # type: ignore[attr-defined]
    saves: list[int] = []
    real_save = live.save
    live.save = lambda: (saves.append(1), real_save())[1]
    th = threading.Thread(target=asyncio.run, args=(agent.run(),), daemon=True)
    th.start()
    recordings = app.state.hub.recordings.recordings  # type: ignore[attr-defined]
    try:
        deadline = time.monotonic() + WAIT_S
        while True:
            states = {r.id: r.parts["S1"].state for r in list(recordings.values())}
            if all(v == "on_node" for v in states.values()):
                break
            left = sorted(k for k, v in states.items() if v != "on_node")
            assert time.monotonic() < deadline, f"{len(left)} parts never listed: {left[:5]}"
            time.sleep(0.1)
    finally:
        agent.stop()
        th.join(10)
    assert len(states) == N_PARTS
    assert len(saves) <= len(part_batches(store.parts())), len(saves)
    hub = app.state.hub  # type: ignore[attr-defined]
    assert hub.registry.get("S1").rejected_messages == 0


def test_a_part_with_an_overlong_reason_or_a_bad_id_does_not_stop_the_node_connecting(
        server: tuple[Settings, object], tmp_path: Path,
        caplog: pytest.LogCaptureFixture) -> None:
    """One part whose reason grew past a control message (a reason gains a clause per
    reopening) or whose meta.json names no valid id used to get the hello refused (4400,
    final): the node never connected. The reason is cut, the bad part left out."""
    settings, app = server
    node_dir = tmp_path / "node"
    store = NodeStore(node_dir / "recordings")
    for k in range(3):
        store.create_part(f"R{k:04d}").close("on_node")
    long_reason = "closed early; not recording again: disk full " * 3000  # ~130 kB
    store.create_part("R0003").close("incomplete", reason=long_reason)
    store.create_part("R0004").close("on_node")
    meta_path = node_dir / "recordings" / "R0004" / "meta.json"
    meta = json.loads(meta_path.read_text())
    meta["rec_id"] = "not a valid id/" + "x" * 100_000
    meta_path.write_text(json.dumps(meta))
    assert len(long_reason) > settings.max_control_bytes
    agent = NodeAgent("S1", _Scripted(), f"ws://127.0.0.1:{settings.port}/ws/node", NODE_TOKEN,
                      node_dir)
    th = threading.Thread(target=asyncio.run, args=(agent.run(),), daemon=True)
    th.start()
    recordings = app.state.hub.recordings.recordings  # type: ignore[attr-defined]
    try:
        deadline = time.monotonic() + WAIT_S
        while recordings["R0003"].parts["S1"].state == "recording":
            assert th.is_alive(), "the node stopped (its hello was refused)"
            assert time.monotonic() < deadline, "the node's listing never arrived"
            time.sleep(0.1)
    finally:
        agent.stop()
        th.join(10)
    assert [recordings[f"R{k:04d}"].parts["S1"].state for k in range(3)] == ["on_node"] * 3
    part = recordings["R0003"].parts["S1"]
    assert part.state == "incomplete"
    assert part.reason is not None and part.reason.endswith("\u2026")
    assert long_reason.startswith(part.reason[:-1]) and len(part.reason) <= 500
    assert recordings["R0004"].parts["S1"].state != "on_node"  # never listed
    assert "R0004" in caplog.text and "not listed" in caplog.text
