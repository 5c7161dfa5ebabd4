"""The node websocket's connection handling: a replaced connection stops at once, and
connections waiting for their hello are bounded per address and in all.

The replacement test drives :meth:`Hub.handle_node` with in-memory websockets, so which
message is buffered when is exact; the slot tests use a real server on loopback with a real
node agent and raw websocket clients from other loopback addresses (127.0.0.x).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
import threading
import time
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import uvicorn
from starlette.websockets import WebSocketState
from websockets.asyncio.client import ClientConnection, connect

from app.config import Settings
from app.main import create_app
from app.nodes.agent import NodeAgent
from app.nodes.protocol import (
    Hello,
    PartInfo,
    RecState,
    Status,
    dump,
    encode_skeletons,
)
from app.server import hub as hub_module
from app.server.hub import (
    CLOSE_BUSY,
    CLOSE_REPLACED,
    HELLO_TIMEOUT_S,
    MAX_PENDING_HELLOS,
    MAX_PENDING_HELLOS_PER_ADDRESS,
    Hub,
)
from tests.app.test_agent import _Scripted  # a sensor that sends nothing

NODE_TOKEN = "test-node-token"
WAIT_S = 30.0  # only a bound for a broken test; nothing is timed


class _Client:
    def __init__(self, host: str, port: int) -> None:
        self.host, self.port = host, port


class FakeSocket:
    """The part of Starlette's ``WebSocket`` the hub uses, in memory: what the test
    feeds is what the transport had buffered, handed out one ``receive()`` at a time."""

    def __init__(self, host: str = "10.0.0.5", port: int = 40000) -> None:
        self.client = _Client(host, port)
        self.application_state = WebSocketState.CONNECTING
        self.inbox: asyncio.Queue[dict[str, Any]] = asyncio.Queue()
        self.sent: list[dict[str, Any]] = []
        self.close_code: int | None = None

    async def accept(self) -> None:
        self.application_state = WebSocketState.CONNECTED

    async def receive(self) -> dict[str, Any]:
        return await self.inbox.get()

    async def send_text(self, text: str) -> None:
        if self.application_state != WebSocketState.CONNECTED:
            raise RuntimeError("websocket is closed")
        self.sent.append(json.loads(text))

    async def close(self, code: int = 1000, reason: str | None = None) -> None:
        self.close_code = code
        self.application_state = WebSocketState.DISCONNECTED

    def feed(self, text: str | None = None, data: bytes | None = None) -> None:
        self.inbox.put_nowait({"type": "websocket.receive", "text": text, "bytes": data})

    def hang_up(self) -> None:
        self.inbox.put_nowait({"type": "websocket.disconnect", "code": 1000})

    async def answered(self, kind: str) -> dict[str, Any]:
        for _ in range(2000):
            for m in self.sent:
                if m["type"] == kind:
                    return m
            await asyncio.sleep(0.005)
        raise AssertionError(f"no {kind!r} sent; sent: {[m['type'] for m in self.sent]}")


def _skeleton(seq: int) -> bytes:
    return encode_skeletons(seq, 1.0 + seq / 30.0, np.zeros((1, 25, 3), np.float32),
                            np.full((1, 25), 2, np.uint8))


def test_a_replaced_connection_handles_nothing_it_had_buffered(tmp_path: Path) -> None:
    """A node reconnects while its old connection still has messages buffered (a status,
    a part's state, skeleton frames). Those arrive at the old connection's loop after the
    new connection took over; they must not act on the node (a stale part state would
    change the recording, a stale status the node's health)."""
    settings = Settings(data_dir=tmp_path, viewer_enabled=False, node_token=NODE_TOKEN,
                        admin_password="secret-pw")

    async def scenario() -> None:
        hub = Hub(settings)
        parts: list[tuple[str, str, str]] = []
        hub.recordings.on_part = (  # type: ignore[method-assign]
            lambda node_id, part, **kw: bool(parts.append((node_id, part.rec_id, part.state))))
        hello = dump(Hello(node_id="S1", token=NODE_TOKEN))
        old = FakeSocket(port=40001)
        t_old = asyncio.create_task(hub.handle_node(old))
        old.feed(hello)
        await old.answered("welcome")
        old.feed(data=_skeleton(1))
        while hub.registry.nodes["S1"].frames_received < 1:  # taken while it is current
            await asyncio.sleep(0.005)

        new = FakeSocket(port=40002)
        t_new = asyncio.create_task(hub.handle_node(new))
        new.feed(hello)
        await new.answered("welcome")
        assert old.close_code == CLOSE_REPLACED
        session = hub.registry.nodes["S1"]
        # what the old connection had buffered reaches its loop only now
        old.feed(dump(Status(fps=12.0, frames=999)))
        old.feed(dump(RecState(part=PartInfo(rec_id="R1", state="incomplete",
                                             reason="stale"))))
        old.feed(data=_skeleton(2))
        old.hang_up()
        await asyncio.wait_for(t_old, 5)
        assert parts == [] and session.status is None
        assert session.frames_received == 1 and session.rejected_messages == 0
        assert session.connected  # the old loop's end did not take the node offline
        assert hub._sockets["S1"] is new

        # the new connection is served as usual
        new.feed(dump(RecState(part=PartInfo(rec_id="R1", state="on_node"))))
        new.feed(dump(Status(fps=30.0, frames=5)))
        while session.status is None:
            await asyncio.sleep(0.005)
        assert parts == [("S1", "R1", "on_node")] and session.status.frames == 5
        new.hang_up()
        await asyncio.wait_for(t_new, 5)
        assert not session.connected and "S1" not in hub._sockets

    asyncio.run(scenario())


def test_a_node_gone_before_its_welcome_is_not_left_connected(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path, viewer_enabled=False, node_token=NODE_TOKEN,
                        admin_password="secret-pw")

    class GoneSocket(FakeSocket):
        async def send_text(self, text: str) -> None:
            raise RuntimeError("connection reset")

    async def scenario() -> None:
        hub = Hub(settings)
        ws = GoneSocket()
        ws.feed(dump(Hello(node_id="S1", token=NODE_TOKEN)))
        await asyncio.wait_for(hub.handle_node(ws), 5)
        assert not hub.registry.nodes["S1"].connected and "S1" not in hub._sockets

    asyncio.run(scenario())


# --------------------------------------------------------------------------- real server


def free_port() -> int:
    """A loopback port nothing listens on at the moment."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def serving(app: Any, port: int) -> Iterator[None]:
    """``app`` served by uvicorn on ``127.0.0.1:port`` in a thread, until the block ends."""
    srv = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port,
                                        log_level="warning"))
    th = threading.Thread(target=srv.run, daemon=True)
    th.start()
    deadline = time.monotonic() + WAIT_S
    while not srv.started:
        assert time.monotonic() < deadline, "server did not start"
        time.sleep(0.05)
    try:
        yield
    finally:
        srv.should_exit = True
        th.join(10)


@pytest.fixture
def server(tmp_path: Path) -> Iterator[tuple[Settings, Hub]]:
    """A real server on a loopback port (all of 127.0.0.0/8 reaches it), and its hub."""
    port = free_port()
    settings = Settings(data_dir=tmp_path / "server", viewer_enabled=False,
                        node_token=NODE_TOKEN, admin_password="secret-pw", port=port)
    (tmp_path / "server").mkdir()
    app = create_app(settings)
    with serving(app, port):
        yield settings, app.state.hub


@contextlib.asynccontextmanager
async def _silent(url: str, host: str, n: int) -> AsyncIterator[list[ClientConnection]]:
    """``n`` websocket connections from ``host`` that never say hello (a slowloris)."""
    async with contextlib.AsyncExitStack() as stack:
        conns = [await stack.enter_async_context(
            connect(url, local_addr=(host, 0), open_timeout=5, ping_interval=None))
            for _ in range(n)]
        yield conns


async def _counted(hub: Hub, n: int) -> None:
    """Wait until the hub counts ``n`` connections waiting for their hello (a client's
    connection is open a moment before the server's side counts it)."""
    deadline = time.monotonic() + WAIT_S
    while hub._pending_hellos < n:
        assert time.monotonic() < deadline, hub._pending_hellos
        await asyncio.sleep(0.02)


async def _refusal(url: str, host: str) -> tuple[dict[str, Any], int | None]:
    async with connect(url, local_addr=(host, 0), open_timeout=5) as ws:
        msg = json.loads(await asyncio.wait_for(ws.recv(), 5))
        with contextlib.suppress(Exception):
            await asyncio.wait_for(ws.wait_closed(), 5)
        return msg, ws.close_code


def test_one_address_flooding_hellos_does_not_lock_other_nodes_out(
        server: tuple[Settings, Hub], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A peer at 127.0.0.2 opens connections and never says hello: it gets
    MAX_PENDING_HELLOS_PER_ADDRESS slots, a further one is told to come back later
    (1013), and a real node at 127.0.0.1 still connects while the flood holds its slots.
    The global cap still holds across addresses."""
    settings, hub = server
    url = f"ws://127.0.0.1:{settings.port}/ws/node"
    # the flood must outlast a loaded test machine's slow steps: not a timing test
    monkeypatch.setattr(hub_module, "HELLO_TIMEOUT_S", 300.0)

    async def scenario() -> None:
        async with _silent(url, "127.0.0.2", MAX_PENDING_HELLOS_PER_ADDRESS):
            await _counted(hub, MAX_PENDING_HELLOS_PER_ADDRESS)
            msg, code = await _refusal(url, "127.0.0.2")
            assert msg["type"] == "refused" and code == CLOSE_BUSY
            assert "127.0.0.2" in msg["reason"] and "try again" in msg["reason"]
            agent = NodeAgent("S1", _Scripted(), url, NODE_TOKEN, tmp_path / "node")
            run = asyncio.create_task(agent.run())
            try:
                deadline = time.monotonic() + WAIT_S
                while agent._ws is None:  # welcomed
                    assert not run.done(), run
                    assert time.monotonic() < deadline, "the node never got in"
                    await asyncio.sleep(0.05)
                # ... while the flood still held its slots
                assert hub._pending_by_address == {"127.0.0.2": MAX_PENDING_HELLOS_PER_ADDRESS}
            finally:
                agent.stop()
                await asyncio.wait_for(run, 10)
        # the global cap: the slots of other addresses fill it; the next one waits
        hosts = [f"127.0.0.{k}" for k in range(3, 3 + MAX_PENDING_HELLOS)]
        per = MAX_PENDING_HELLOS_PER_ADDRESS
        async with contextlib.AsyncExitStack() as stack:
            for k in range(MAX_PENDING_HELLOS // per):
                await stack.enter_async_context(_silent(url, hosts[k], per))
            await _counted(hub, MAX_PENDING_HELLOS)
            msg, code = await _refusal(url, hosts[-1])
            assert code == CLOSE_BUSY and f"{MAX_PENDING_HELLOS} connections" in msg["reason"]

    asyncio.run(scenario())


def test_nodes_on_the_servers_own_machine_may_all_connect_at_once(
        server: tuple[Settings, Hub], monkeypatch: pytest.MonkeyPatch) -> None:
    """The demo's six nodes run on the server's machine and open their connections in the
    same instant: from 127.0.0.1 more than MAX_PENDING_HELLOS_PER_ADDRESS may wait for
    their hello (the third was refused, and the demo's log began with warnings); the
    global cap still holds there."""
    settings, hub = server
    url = f"ws://127.0.0.1:{settings.port}/ws/node"
    monkeypatch.setattr(hub_module, "HELLO_TIMEOUT_S", 300.0)
    n = MAX_PENDING_HELLOS_PER_ADDRESS + 3
    assert n < MAX_PENDING_HELLOS

    async def scenario() -> None:
        async with _silent(url, "127.0.0.1", n):
            await _counted(hub, n)
            assert hub._pending_by_address == {"127.0.0.1": n}
        async with _silent(url, "127.0.0.1", MAX_PENDING_HELLOS):
            await _counted(hub, MAX_PENDING_HELLOS)
            msg, code = await _refusal(url, "127.0.0.1")
            assert code == CLOSE_BUSY and f"{MAX_PENDING_HELLOS} connections" in msg["reason"]

    asyncio.run(scenario())


def test_a_silent_connection_is_closed_after_the_hello_timeout(
        server: tuple[Settings, Hub], monkeypatch: pytest.MonkeyPatch) -> None:
    url = f"ws://127.0.0.1:{server[0].port}/ws/node"
    assert HELLO_TIMEOUT_S == 5.0  # the default docs/backbone.md and docs/security.md give
    # a short timeout, read when the connection opens: the test waits it out, not 5 s
    monkeypatch.setattr(hub_module, "HELLO_TIMEOUT_S", 0.3)

    async def scenario() -> None:
        async with connect(url, open_timeout=5, ping_interval=None) as ws:
            msg = json.loads(await asyncio.wait_for(ws.recv(), WAIT_S))
            assert msg["type"] == "refused"
            assert "no hello within 0.3 s" in msg["reason"]

    asyncio.run(scenario())
