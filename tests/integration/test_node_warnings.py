"""Backend warnings raised after a node connected reach the server's node health: a real
sim node process told to raise one (``--test-warning``), a real server, loopback; and a
node of the older protocol revision, or a flooding one, next to it."""

from __future__ import annotations

import asyncio
import json
import time

import pytest
from websockets.asyncio.client import connect

from app.nodes.protocol import Hello, NodeWarning, dump
from app.server.registry import NODE_WARNINGS_KEPT, NODE_WARNINGS_PER_MINUTE
from tests.integration.conftest import TOKEN, Rig, wait_for

pytestmark = pytest.mark.slow

TEXT = "Body tracking fell behind the camera (test warning): skeletons may be missing."


def test_a_sim_node_warning_reaches_the_node_health_with_its_time(make_rig: object) -> None:
    rig: Rig = make_rig()  # type: ignore[operator]
    t0 = time.time()
    rig.start_node("S1", "--test-warning", TEXT)
    rig.wait_online(["S1"])
    n = wait_for(lambda: (rig.nodes()["S1"]["node_warnings"] or None) and rig.nodes()["S1"],
                 60, "the node's warning")
    w = n["node_warnings"][0]
    assert w["text"] == TEXT and t0 < w["at"] <= time.time() + 0.5
    assert TEXT not in n["warnings"]  # its own list, with times, not the health checks
    # raised every 5 s: the repeats coalesce into one entry that says how often
    n = wait_for(lambda: rig.nodes()["S1"]["node_warnings"][0]["repeats"] >= 2
                 and rig.nodes()["S1"], 60, "a repeat of the warning")
    assert [x["text"] for x in n["node_warnings"]] == [TEXT]
    assert n["node_warnings"][0]["at"] > w["at"] and n["rejected_messages"] == 0
    assert "S1 warns: " + TEXT in rig.log_text("server")
    assert TEXT in rig.log_text("S1")


def test_older_nodes_get_the_welcome_they_know_and_floods_are_bounded(
        make_rig: object) -> None:
    """A node of revision 1 (before warnings) gets a welcome without ``accepts``: its
    parser refuses unknown fields. A node sending far more warnings than an agent would
    (a broken or hostile one) keeps its connection; the server keeps a few, counts the rest."""
    rig: Rig = make_rig()  # type: ignore[operator]
    url = f"ws://127.0.0.1:{rig.port}/ws/node"

    async def welcome(revision: int) -> dict[str, object]:
        async with connect(url, open_timeout=5) as ws:
            await ws.send(dump(Hello(node_id=f"R{revision}", token=TOKEN, protocol=revision)))
            return dict(json.loads(await asyncio.wait_for(ws.recv(), 5)))

    old = asyncio.run(welcome(1))
    assert old["type"] == "welcome"
    assert set(old) == {"v", "type", "server_time", "ping_interval_s"}
    assert asyncio.run(welcome(2))["accepts"] == ["warning", "sensor_lens"]

    async def flood() -> None:
        async with connect(url, open_timeout=5) as ws:
            await ws.send(dump(Hello(node_id="F1", token=TOKEN)))
            await asyncio.wait_for(ws.recv(), 5)
            for k in range(3 * NODE_WARNINGS_PER_MINUTE):
                await ws.send(dump(NodeWarning(text=f"warning {k}", t=time.time())))
            await ws.send(dump(NodeWarning(text="x" * 5000, t=time.time())))  # cut, kept
            wait_for(lambda: rig.nodes()["F1"]["node_warnings_dropped"] > 0, 30,
                     "the flood counted")
            assert not ws.close_code

    asyncio.run(flood())
    n = rig.nodes()["F1"]
    assert len(n["node_warnings"]) == NODE_WARNINGS_KEPT
    assert n["node_warnings_dropped"] == 2 * NODE_WARNINGS_PER_MINUTE + 1
    assert n["node_warnings"][0]["text"] == f"warning {NODE_WARNINGS_PER_MINUTE - 1}"
    assert n["rejected_messages"] == 0
