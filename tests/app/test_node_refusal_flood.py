"""Refused node messages are bounded per connection: a flood is counted, summarised once a
window (log and the node's health on the Rig page) and, past a generous bound, closed with
a reason the node sees; a working node next to it is untouched.

A real server on loopback (uvicorn in a thread, so ``caplog`` sees its log) and raw
websocket clients speaking the node protocol.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed

from app.config import Settings
from app.main import create_app
from app.nodes.protocol import Hello, Pong, Status, dump, encode_skeletons
from app.server import hub as hub_module
from app.server.hub import (
    CLOSE_FLOOD,
    MAX_REFUSED_PER_WINDOW,
    REFUSAL_BURST,
    Hub,
    RefusalBudget,
)
from tests.app.test_hub_connections import NODE_TOKEN, free_port, serving

PASSWORD = "secret-pw"
WAIT_S = 30.0  # only a bound for a broken test; nothing is timed


@pytest.fixture
def server(tmp_path: Path) -> Iterator[tuple[Settings, Hub]]:
    port = free_port()
    settings = Settings(data_dir=tmp_path / "server", viewer_enabled=False,
                        node_token=NODE_TOKEN, admin_password=PASSWORD, port=port)
    (tmp_path / "server").mkdir()
    app = create_app(settings)
    with serving(app, port):
        yield settings, app.state.hub


def _nodes(settings: Settings) -> dict[str, dict[str, Any]]:
    """``GET /api/nodes`` as the Rig page reads it."""
    base = f"http://127.0.0.1:{settings.port}"
    req = urllib.request.Request(base + "/api/auth/login", method="POST",
                                 data=json.dumps({"username": "admin",
                                                  "password": PASSWORD}).encode(),
                                 headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=10) as r:
        token = json.loads(r.read())["token"]
    req = urllib.request.Request(base + "/api/nodes",
                                 headers={"Authorization": f"Bearer {token}"})
    with urllib.request.urlopen(req, timeout=10) as r:
        return {n["id"]: n for n in json.loads(r.read())}


async def _hello(url: str, node_id: str) -> ClientConnection:
    # max_queue=None: a test that reads nothing for a while (pings, refusals arriving)
    # must still see the close frame; a full queue stops reading and close() waited 10 s
    ws = await connect(url, open_timeout=5, max_size=None, ping_interval=None, max_queue=None)
    await ws.send(dump(Hello(node_id=node_id, token=NODE_TOKEN)))
    assert json.loads(await asyncio.wait_for(ws.recv(), 5))["type"] == "welcome"
    return ws


async def _drain(ws: ClientConnection) -> list[dict[str, Any]]:
    """Every message the server sends until it closes the connection, pings answered."""
    got: list[dict[str, Any]] = []
    try:
        while True:
            m = json.loads(await asyncio.wait_for(ws.recv(), WAIT_S))
            got.append(m)
    except ConnectionClosed:
        return got


def _hub_records(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == "gaitrig.hub"]


def test_budget_answers_a_burst_then_counts_and_summarises_each_window() -> None:
    b = RefusalBudget("S1")
    t = 100.0
    answered = [b.refuse(f"bad {k}", t) for k in range(REFUSAL_BURST + 30)]
    assert answered == [True] * REFUSAL_BURST + [False] * 30
    assert b.summary(t + 1.0) is None  # the window is still open
    text = b.summary(t + hub_module.REFUSAL_WINDOW_S)
    assert text is not None and f"{REFUSAL_BURST + 30} messages refused" in text
    assert "30 of them counted only" in text and "the first: bad 0" in text
    assert b.summary(t + 100.0) is None  # said once; nothing refused since
    # the bucket refills: a refusal now and then is always answered
    assert all(b.refuse("rare", t + 100.0 + 5.0 * k) for k in range(50))
    assert b.summary() is None  # nothing counted only: nothing to summarise
    assert not b.flooding


def test_a_flood_of_refused_messages_is_bounded_and_closed(
        server: tuple[Settings, Hub], caplog: pytest.LogCaptureFixture) -> None:
    """A node sends 3 000 messages the server refuses (not JSON, then unknown binary)
    as fast as it can, next to a working node streaming skeleton frames, statuses and
    pongs. The flood: at most a burst answered and logged one by one, one summary with the
    first reason (in the log and the node's health), then the connection closed with
    1008 and a reason the node reads. The working node: every message taken, nothing
    refused, still connected."""
    settings, hub = server
    url = f"ws://127.0.0.1:{settings.port}/ws/node"
    caplog.set_level(logging.INFO, logger="gaitrig.hub")
    n_flood = 3 * MAX_REFUSED_PER_WINDOW

    async def good_node(stop: asyncio.Event) -> int:
        ws = await _hello(url, "GOOD")
        seq = 0
        while not stop.is_set():
            seq += 1
            await ws.send(encode_skeletons(seq, time.time(), np.zeros((1, 25, 3), np.float32),
                                           np.full((1, 25), 2, np.uint8)))
            if seq % 10 == 0:
                await ws.send(dump(Status(fps=30.0, frames=seq)))
                await ws.send(dump(Pong(seq=seq, t1=time.time(), t2=time.time(),
                                        t3=time.time())))
            await asyncio.sleep(0.002)
        await ws.close()
        return seq

    async def scenario() -> tuple[list[dict[str, Any]], int | None, str | None, int]:
        stop = asyncio.Event()
        good = asyncio.create_task(good_node(stop))
        ws = await _hello(url, "FLOOD")
        reader = asyncio.create_task(_drain(ws))
        try:
            for k in range(n_flood):
                await ws.send("{not json" if k % 2 == 0 else b"GRB\x01garbage")
        except ConnectionClosed:
            pass  # closed by the server part-way: what this test wants
        got = await reader
        stop.set()
        sent = await asyncio.wait_for(good, WAIT_S)
        rcvd = ws.protocol.close_rcvd
        return got, rcvd.code if rcvd else None, rcvd.reason if rcvd else None, sent

    got, code, reason, good_sent = asyncio.run(scenario())

    # the node sees why it was closed
    assert code == CLOSE_FLOOD, (code, reason)
    assert reason and "refused messages" in reason and "not valid JSON" in reason, reason
    errors = [m for m in got if m["type"] == "error"]
    # the burst, one 'counted, not answered' notice, and the closing reason
    assert REFUSAL_BURST < len(errors) <= REFUSAL_BURST + 5, len(errors)
    assert any("counted, not answered" in m["reason"] for m in errors)
    assert "refused messages" in errors[-1]["reason"]

    flood = hub.registry.nodes["FLOOD"]
    assert MAX_REFUSED_PER_WINDOW < flood.rejected_messages < n_flood
    logged = _hub_records(caplog)
    one_by_one = [m for m in logged if m.startswith("rejected message from node FLOOD")]
    assert REFUSAL_BURST - 5 <= len(one_by_one) <= REFUSAL_BURST + 5, len(one_by_one)
    summaries = [m for m in logged if "messages refused in the last" in m]
    assert len(summaries) == 1, summaries
    assert summaries[0].startswith("node FLOOD: ") and "the first: control message is not " \
        "valid JSON" in summaries[0]
    assert sum("FLOOD" in m for m in logged) <= REFUSAL_BURST + 10  # bounded, whatever sent

    nodes = _nodes(settings)
    assert any("messages refused in the last" in w for w in nodes["FLOOD"]["warnings"])
    good = nodes["GOOD"]
    assert good["rejected_messages"] == 0 and good["frames"] == good_sent
    assert not any("refused" in w for w in good["warnings"])


def test_a_burst_that_stops_is_summarised_and_the_connection_kept(
        server: tuple[Settings, Hub], caplog: pytest.LogCaptureFixture,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Fewer refused messages than the closing bound, then silence: the connection stays,
    the summary comes once the window ends (no further message needed to trigger it) and
    the Rig page's node list shows it; later good messages are served."""
    settings, _ = server
    url = f"ws://127.0.0.1:{settings.port}/ws/node"
    caplog.set_level(logging.INFO, logger="gaitrig.hub")
    monkeypatch.setattr(hub_module, "REFUSAL_WINDOW_S", 1.0)
    n_bad = REFUSAL_BURST + 100

    async def scenario() -> dict[str, Any]:
        ws = await _hello(url, "S2")
        for _ in range(n_bad):
            await ws.send(json.dumps({"type": "status", "fps": "fast"}))
        deadline = time.monotonic() + WAIT_S
        while not any("messages refused in the last" in m for m in _hub_records(caplog)):
            assert time.monotonic() < deadline, "no summary logged"
            await asyncio.sleep(0.05)
        node = await asyncio.to_thread(lambda: _nodes(settings)["S2"])
        await ws.send(dump(Status(fps=30.0, frames=1)))
        # still served: it answers pings
        while json.loads(await asyncio.wait_for(ws.recv(), 5))["type"] != "ping":
            pass
        assert ws.close_code is None
        await ws.close()
        return node

    node = asyncio.run(scenario())
    assert node["connected"] and node["rejected_messages"] == n_bad
    notes = [w for w in node["warnings"] if "messages refused in the last" in w]
    assert len(notes) == 1 and f"{n_bad} messages refused" in notes[0]
    assert "invalid 'status'" in notes[0]
    one_by_one = [m for m in _hub_records(caplog) if m.startswith("rejected message from")]
    assert len(one_by_one) <= REFUSAL_BURST + 5
