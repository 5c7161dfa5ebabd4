"""Node agent recording logic, driven frame by frame (no server, no threads)."""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import subprocess
import threading
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import pytest

from app.nodes.agent import MAX_IMAGE_BACKLOG, NodeAgent
from app.nodes.backends.base import Backend, Frame
from app.nodes.protocol import PROTOCOL_REVISION, PartVerified, RecStart, RecStop, SensorInfo
from app.nodes.store import NodeStore, RetentionPolicy
from tests.tmpfs import mounted_tmpfs

DT = 1.0 / 30.0


class _Scripted(Backend):
    name = "scripted"

    def open(self) -> SensorInfo:
        return SensorInfo()

    def frames(self) -> Iterator[Frame]:
        return iter(())

    def __init__(self) -> None:
        self.step = 0.0  # a step of the system clock (NTP)

    def now(self) -> float:
        return time.time() + self.step


def _frame(k: int) -> Frame:
    return Frame(k * DT, np.full((1, 25, 3), k, np.float32), np.full((1, 25), 2, np.uint8), [0])


def _times(store: NodeStore, rec_id: str) -> list[float]:
    return [h["t"] for h, _ in store.read(rec_id) if h["kind"] == "skeleton"]


@pytest.fixture
def agent(tmp_path: Path) -> NodeAgent:
    return NodeAgent("S1", _Scripted(), "ws://127.0.0.1:1/ws/node", "token", tmp_path)


def test_late_start_and_late_stop(agent: NodeAgent) -> None:
    k = 0
    for k in range(45):  # frames up to 1.47 s
        agent._on_frame(_frame(k))
    agent._on_command(RecStart(rec_id="R1", t_start_server=0.0, t_start_local=1.0))
    for k in range(45, 70):  # up to 2.3 s: written while the stop travels
        agent._on_frame(_frame(k))
    agent._on_command(RecStop(rec_id="R1", t_stop_server=0.0, t_stop_local=2.0))
    ts = _times(agent.store, "R1")
    assert ts[0] == pytest.approx(30 * DT) and ts[-1] == pytest.approx(60 * DT)
    assert len(ts) == 31
    assert agent.store.parts()[0].state == "on_node"


def test_stop_in_the_future_waits(agent: NodeAgent) -> None:
    for k in range(10):
        agent._on_frame(_frame(k))
    agent._on_command(RecStart(rec_id="R2", t_start_server=0.0, t_start_local=0.5))
    agent._on_command(RecStop(rec_id="R2", t_stop_server=0.0, t_stop_local=1.0))
    assert agent.store.parts()[0].state == "recording"
    for k in range(10, 40):
        agent._on_frame(_frame(k))
    ts = _times(agent.store, "R2")
    assert ts[0] == pytest.approx(15 * DT) and ts[-1] == pytest.approx(30 * DT)
    assert agent.store.parts()[0].state == "on_node"


def test_stop_overtaking_start(agent: NodeAgent) -> None:
    for k in range(80):
        agent._on_frame(_frame(k))
    agent._on_command(RecStop(rec_id="R3", t_stop_server=0.0, t_stop_local=2.2))
    agent._on_command(RecStart(rec_id="R3", t_start_server=0.0, t_start_local=2.0))
    ts = _times(agent.store, "R3")
    assert ts[0] == pytest.approx(60 * DT) and ts[-1] == pytest.approx(66 * DT)
    assert agent.store.parts()[0].state == "on_node"
    agent._on_command(RecStart(rec_id="R3", t_start_server=0.0, t_start_local=2.0))
    assert len(agent.store.parts()) == 1  # a resent start is ignored


@pytest.fixture
def tiny_disk(tmp_path: Path) -> Iterator[Path]:
    """A 64 KiB tmpfs: a node disk that fills up within a few seconds of skeletons."""
    with mounted_tmpfs(tmp_path / "tiny", "64k") as mnt:
        yield mnt


def test_disk_full_closes_the_part_incomplete_and_keeps_the_frames(tiny_disk: Path) -> None:
    agent = NodeAgent("S1", _Scripted(), "ws://127.0.0.1:1/ws/node", "token", tiny_disk)
    agent._on_command(RecStart(rec_id="R4", t_start_server=0.0, t_start_local=0.0))
    for k in range(400):  # ~250 bytes a frame: the disk is full long before the end
        agent._on_frame(_frame(k))  # never raises: the live stream goes on
    assert "R4" not in agent._recs
    part = agent.store.parts()[0]
    assert part.state == "incomplete"
    assert part.reason is not None and "S1's disk is full" in part.reason
    ts = _times(agent.store, "R4")
    assert 50 < len(ts) == part.n_frames < 400  # every frame written before is readable
    assert ts == pytest.approx([k * DT for k in range(len(ts))])
    # a frames.bin without a torn record at the end, and the server is told
    assert (tiny_disk / "recordings" / "R4" / "frames.bin").stat().st_size == part.bytes
    assert agent._finished["R4"][0].state == "incomplete"
    agent._on_command(RecStop(rec_id="R4", t_stop_server=0.0, t_stop_local=99.0))  # no-op


def test_start_on_a_full_disk_is_reported_as_the_parts_state(tiny_disk: Path) -> None:
    agent = NodeAgent("S1", _Scripted(), "ws://127.0.0.1:1/ws/node", "token", tiny_disk)
    ballast = tiny_disk / "ballast"
    with open(ballast, "wb") as f, contextlib.suppress(OSError):
        f.write(b"\0" * (1 << 20))
    agent._on_command(RecStart(rec_id="R5", t_start_server=0.0, t_start_local=0.0))
    info, _ = agent._finished["R5"]  # re-announced with the status until the server has it
    assert info.state == "incomplete" and info.n_frames == 0
    assert info.reason == "node S1's disk is full; nothing was recorded there"
    agent._on_frame(_frame(1))


def test_start_on_a_read_only_disk_says_so(tiny_disk: Path) -> None:
    agent = NodeAgent("S1", _Scripted(), "ws://127.0.0.1:1/ws/node", "token", tiny_disk)
    subprocess.run(["mount", "-o", "remount,ro", str(tiny_disk)], check=True)
    agent._on_command(RecStart(rec_id="R8", t_start_server=0.0, t_start_local=0.0))
    info, _ = agent._finished["R8"]
    assert info.state == "incomplete"
    assert info.reason == "node S1's recordings folder is read-only; nothing was recorded there"


def test_slow_image_encoding_keeps_memory_bounded(agent: NodeAgent) -> None:
    release = threading.Event()
    rendered = []

    def images(streams: Sequence[str]) -> dict[str, np.ndarray]:
        release.wait(10)  # an encoder far behind the sensor
        rendered.append(1)
        return {"depth": np.zeros((4, 4), np.uint16)}

    agent._on_command(RecStart(rec_id="R6", t_start_server=0.0, t_start_local=0.0,
                               streams=["depth"]))
    for k in range(300):  # ten seconds of frames, each asking for its depth image
        f = _frame(k)
        f.images = images
        agent._on_frame(f)
    rec = agent._recs["R6"]
    assert len(rec.pending_images) <= MAX_IMAGE_BACKLOG  # not 300 frames' images held
    assert rec.images_skipped == 300 - MAX_IMAGE_BACKLOG
    release.set()
    agent._on_command(RecStop(rec_id="R6", t_stop_server=0.0, t_stop_local=250 * DT))
    recorded = [h for h, _ in agent.store.read("R6") if h["kind"] == "image"]
    assert len(recorded) == len(rendered) == MAX_IMAGE_BACKLOG
    assert len(_times(agent.store, "R6")) == 251  # every skeleton frame is kept
    assert agent.store.meta("R6")["images_skipped"] == 300 - MAX_IMAGE_BACKLOG


@pytest.mark.parametrize("step", [0.5, -0.5, 0.05])
@pytest.mark.parametrize("frames_step", [True, False])
def test_a_clock_step_keeps_recorded_times_continuous(tmp_path: Path, step: float,
                                                      frames_step: bool) -> None:
    backend = _Scripted()
    agent = NodeAgent("S1", backend, "ws://127.0.0.1:1/ws/node", "token", tmp_path)
    truth: list[float] = []  # when each frame was really captured

    def frame(k: int) -> Frame:
        # stamped by the backend's clock when captured, or by a device clock that does
        # not step with the system's (a sensor's own timestamps)
        truth.append(time.time())
        return Frame(backend.now() if frames_step else truth[-1],
                     np.full((1, 25, 3), k, np.float32), np.full((1, 25), 2, np.uint8), [0])

    agent._on_command(RecStart(rec_id="R7", t_start_server=0.0, t_start_local=agent.now()))
    for k in range(20):
        agent._on_frame(frame(k))
    stale = frame(20)  # captured before the step, handled after it
    backend.step = step
    agent._on_frame(stale)
    for k in range(21, 60):
        agent._on_frame(frame(k))
        if k == 40 and step == 0.5 and not frames_step:
            time.sleep(2.1)  # the device-clock frames stay right long after the step
    ts = np.array(_times(agent.store, "R7"))
    assert agent.clock_steps == 1 and agent.dropped == 0
    assert len(ts) == 60  # nothing lost to a clock going backwards
    # every frame on one continuous clock: the step is in none of the recorded times
    assert np.abs(ts - np.array(truth)).max() < 0.005
    assert abs(agent.now() - time.time()) < 0.005


def _recorded(agent: NodeAgent, rec_id: str) -> None:
    for k in range(40):
        agent._on_frame(_frame(k))
    agent._on_command(RecStart(rec_id=rec_id, t_start_server=0.0, t_start_local=0.5))
    agent._on_command(RecStop(rec_id=rec_id, t_stop_server=0.0, t_stop_local=1.0))


def _manifest_sha(agent: NodeAgent, rec_id: str) -> str:
    return hashlib.sha256(agent._manifest(rec_id).to_json().encode()).hexdigest()


def test_a_part_the_server_verified_is_purged_with_keep_zero_days(tmp_path: Path) -> None:
    agent = NodeAgent("S1", _Scripted(), "ws://127.0.0.1:1/ws/node", "token", tmp_path,
                      retention=RetentionPolicy(keep_verified_s=0, min_free_bytes=0,
                                                min_free_fraction=0))
    _recorded(agent, "R1")
    _recorded(agent, "R2")
    # a verification against another manifest (not this node's part as it is) is ignored
    asyncio.run(agent._on_verified(PartVerified(rec_id="R1", manifest_sha256="0" * 64)))
    assert agent.store.verified_at("R1") is None and agent.purged_parts == 0
    asyncio.run(agent._on_verified(PartVerified(rec_id="R1",
                                                manifest_sha256=_manifest_sha(agent, "R1"))))
    assert [p.rec_id for p in agent.store.parts()] == ["R2"]  # R2: not verified, kept
    st = agent.storage(10**12)
    assert st is not None and st.purged_parts == 1 and "R1" in (st.last_purge or "")
    assert st.verified_parts == 0 and st.unverified == ["R2"] and st.held_parts == 1
    assert st.keep_verified_days == 0
    # told again (after a reconnect) about a part it no longer has: nothing happens
    asyncio.run(agent._on_verified(PartVerified(rec_id="R1", manifest_sha256="1" * 64)))
    assert agent.purged_parts == 1


def test_a_verified_part_is_kept_its_days_and_the_mark_survives_a_restart(
        tmp_path: Path) -> None:
    policy = RetentionPolicy(keep_verified_s=7 * 86400.0, min_free_bytes=0,
                             min_free_fraction=0)
    agent = NodeAgent("S1", _Scripted(), "ws://127.0.0.1:1/ws/node", "token", tmp_path,
                      retention=policy)
    _recorded(agent, "R1")
    asyncio.run(agent._on_verified(PartVerified(rec_id="R1",
                                                manifest_sha256=_manifest_sha(agent, "R1"))))
    st = agent.storage(10**12)
    assert st is not None and st.verified_parts == 1 and st.purgeable_bytes > 0
    assert st.unverified == [] and st.purged_parts == 0
    again = NodeAgent("S1", _Scripted(), "ws://127.0.0.1:1/ws/node", "token", tmp_path,
                      retention=policy)
    assert again.store.verified_at("R1") is not None
    assert again.store.usage().verified_parts == 1


def test_a_restarted_node_records_again_into_its_part(tmp_path: Path) -> None:
    first = NodeAgent("S1", _Scripted(), "ws://127.0.0.1:1/ws/node", "token", tmp_path)
    for k in range(10):
        first._on_frame(_frame(k))
    first._on_command(RecStart(rec_id="R1", t_start_server=0.0, t_start_local=0.0))
    for k in range(10, 40):  # up to 1.3 s, then the process dies (no stop, no close)
        first._on_frame(_frame(k))
    # restarted: its (device) clock now counts from another origin, 100 s ahead
    again = NodeAgent("S1", _Scripted(), "ws://127.0.0.1:1/ws/node", "token", tmp_path)
    assert [p.state for p in again.store.recover()] == ["incomplete"]
    for k in range(30):
        again._on_frame(Frame(100.0 + k * DT, np.full((1, 25, 3), 500 + k, np.float32),
                              np.full((1, 25), 2, np.uint8), [0]))
    # a start resent without resume (a reconnect) changes nothing
    again._on_command(RecStart(rec_id="R1", t_start_server=0.0, t_start_local=100.5))
    assert "R1" not in again._recs
    # the server: record again from local 100.5 = 2.0 s on the part's first clock
    again._on_command(RecStart(rec_id="R1", t_start_server=0.0, t_start_local=100.5,
                               resume=True, rebase_s=-98.5))
    for k in range(30, 70):
        again._on_frame(Frame(100.0 + k * DT, np.full((1, 25, 3), 500 + k, np.float32),
                              np.full((1, 25), 2, np.uint8), [0]))
    again._on_command(RecStop(rec_id="R1", t_stop_server=0.0, t_stop_local=101.5))
    ts = np.array(_times(again.store, "R1"))
    assert len(ts) == 40 + 31 and np.all(np.diff(ts) > 0)
    assert ts[39] == pytest.approx(39 * DT) and ts[40] == pytest.approx(2.0)
    assert ts[-1] == pytest.approx(3.0)
    part = again.store.parts()[0]
    assert part.state == "incomplete" and part.n_frames == 71
    assert "restarted during the recording: 0.7 s are missing" in (part.reason or "")
    meta = again.store.meta("R1")
    assert meta["t_stop_local"] == pytest.approx(3.0) and len(meta["segments"]) == 2
    # a part closed normally is never reopened
    again._on_command(RecStart(rec_id="R1", t_start_server=0.0, t_start_local=102.0,
                               resume=True))
    assert "R1" not in again._recs


@pytest.mark.parametrize(("reason", "code"), [
    ("8 connections are already waiting to say hello; try again in a few seconds", 1013),
    ("too many wrong pairing tokens from 10.0.0.5; connections from it are refused for "
     "290 s more", 1013)])
def test_a_refusal_to_come_back_later_is_retried_not_final(tmp_path: Path, reason: str,
                                                          code: int) -> None:
    """The server refuses with close code 1013 ('try again later') when too many
    connections wait for their hello, or while another process at this node's address
    is paused for guessing the pairing token. The node took every refusal as final and
    stopped for good (a rig of more than eight nodes reconnecting after a server restart
    could lose some of them)."""
    import json

    from websockets.asyncio.server import serve

    from app.nodes.protocol import Refused, Welcome, dump

    seen: list[str] = []

    async def handler(ws: object) -> None:
        hello = json.loads(await ws.recv())  # type: ignore[attr-defined]
        seen.append(hello["type"])
        if len(seen) == 1:
            await ws.send(dump(Refused(reason=reason)))  # type: ignore[attr-defined]
            await ws.close(code=code, reason="try again")  # type: ignore[attr-defined]
            return
        await ws.send(dump(Welcome(server_time=time.time(),  # type: ignore[attr-defined]
                                   ping_interval_s=0.1)))
        # served until the node goes (a fixed 5 s sleep held the server's exit that long)
        await ws.wait_closed()  # type: ignore[attr-defined]

    async def scenario() -> None:
        async with serve(handler, "127.0.0.1", 0) as srv:
            port = next(iter(srv.sockets)).getsockname()[1]
            a = NodeAgent("S1", _Scripted(), f"ws://127.0.0.1:{port}/ws/node", "token",
                          tmp_path)
            a.info = SensorInfo()
            task = asyncio.create_task(a._connect_forever())
            for _ in range(100):
                if len(seen) >= 2 or task.done():
                    break
                await asyncio.sleep(0.05)
            a._stop.set()
            done = task.done()
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
            assert not done or task.exception() is None, "the node gave up"
            assert seen == ["hello", "hello"]

    asyncio.run(scenario())


def test_a_final_refusal_still_ends_the_node(tmp_path: Path) -> None:
    """A wrong pairing token (close code 4401) is not retried: the node stops and says why."""
    import json

    from websockets.asyncio.server import serve

    from app.nodes.agent import NodeRefusedError
    from app.nodes.protocol import Refused, dump

    async def handler(ws: object) -> None:
        json.loads(await ws.recv())  # type: ignore[attr-defined]
        await ws.send(dump(Refused(reason="wrong pairing token")))  # type: ignore[attr-defined]
        await ws.close(code=4401, reason="refused")  # type: ignore[attr-defined]

    async def scenario() -> None:
        async with serve(handler, "127.0.0.1", 0) as srv:
            port = next(iter(srv.sockets)).getsockname()[1]
            a = NodeAgent("S1", _Scripted(), f"ws://127.0.0.1:{port}/ws/node", "token",
                          tmp_path)
            a.info = SensorInfo()
            with pytest.raises(NodeRefusedError, match="wrong pairing token"):
                await asyncio.wait_for(a._connect_forever(), 10)

    asyncio.run(scenario())


def test_backend_warnings_are_coalesced_bounded_and_rate_limited(agent: NodeAgent) -> None:
    from app.nodes.agent import WARNING_BACKLOG, WARNING_BURST
    from app.nodes.protocol import parse_node_message

    def sent() -> list[tuple[str, int]]:
        out = [parse_node_message(m) for m in agent._control]
        agent._control.clear()
        return [(m.text, m.repeats) for m in out if m.type == "warning"]

    agent._queue_warning("before the connection")  # waits: no server yet
    agent._ws = object()  # type: ignore[assignment]  # connected ...
    agent._flush_warnings()
    assert sent() == [] and len(agent._warnings) == 1  # ... to a server that takes none
    agent._server_takes_warnings = True
    for k in range(40):
        agent._queue_warning(f"problem {k}")
    first = sent()
    assert first == [("before the connection", 1)] + [
        (f"problem {k}", 1) for k in range(WARNING_BURST - 1)]
    assert len(agent._warnings) == WARNING_BACKLOG  # the oldest waiting ones dropped
    assert agent.warnings_dropped == 40 - (WARNING_BURST - 1) - WARNING_BACKLOG
    newest = f"problem {39}"
    for _ in range(3):
        agent._queue_warning(f"  {newest}\n")  # the same text (spaces aside): coalesced
    assert len(agent._warnings) == WARNING_BACKLOG and sent() == []
    agent._warning_refilled -= 1000.0  # long after: the bucket is full again
    agent._flush_warnings()
    again = sent()
    assert len(again) == WARNING_BURST and again[0] == ("problem 20", 1)
    while agent._warnings:
        agent._warning_refilled -= 1000.0
        agent._flush_warnings()
        again += sent()
    assert again[-1] == (newest, 4)
    agent._queue_warning("x" * 5000)  # cut to the protocol's bound, still sent
    agent._warning_refilled -= 1000.0
    agent._flush_warnings()
    ((text, _),) = sent()
    assert len(text) == 500 and text.endswith("…")


@pytest.mark.parametrize("accepts", [None, ["warning", "something-later"]])
def test_warnings_go_only_to_a_server_that_takes_them(tmp_path: Path,
                                                      accepts: list[str] | None) -> None:
    """A server before protocol revision 2 welcomes without ``accepts`` (and would answer a
    warning with an error): the node sends it none. One that accepts them gets the
    backend's warning, raised from another thread after the welcome."""
    import json

    from websockets.asyncio.server import serve

    from app.nodes.protocol import Welcome, dump

    hellos: list[dict[str, object]] = []
    types: list[str] = []
    warnings: list[dict[str, object]] = []

    async def handler(ws: object) -> None:
        hellos.append(json.loads(await ws.recv()))  # type: ignore[attr-defined]
        await ws.send(dump(Welcome(server_time=time.time(),  # type: ignore[attr-defined]
                                   ping_interval_s=0.1, accepts=accepts)))
        async for raw in ws:  # type: ignore[attr-defined]
            if isinstance(raw, str):
                m = json.loads(raw)
                types.append(m["type"])
                if m["type"] == "warning":
                    warnings.append(m)

    async def scenario() -> None:
        async with serve(handler, "127.0.0.1", 0) as srv:
            port = next(iter(srv.sockets)).getsockname()[1]
            backend = _Scripted()
            a = NodeAgent("S1", backend, f"ws://127.0.0.1:{port}/ws/node", "token", tmp_path)
            a.info = SensorInfo()
            a._loop = asyncio.get_running_loop()
            task = asyncio.create_task(a._connect_forever())
            while a._ws is None:
                await asyncio.sleep(0.02)
            threading.Thread(target=backend.warn, args=("Body tracking stopped: test",)
                             ).start()
            for _ in range(150):  # two status rounds at least
                if warnings or types.count("status") >= 2:
                    break
                await asyncio.sleep(0.02)
            a._stop.set()
            await asyncio.wait_for(task, 10)

    asyncio.run(scenario())
    assert hellos[0]["protocol"] == PROTOCOL_REVISION >= 2
    if accepts is None:
        assert warnings == [] and types.count("status") >= 2
    else:
        assert [w["text"] for w in warnings] == ["Body tracking stopped: test"]
        assert isinstance(warnings[0]["t"], float)


def test_a_replay_that_falls_behind_warns_through_the_agents_path(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The replay backend falling behind its recorded pace (an overloaded computer) says so
    once a minute through Backend.warn: the log and, via the agent, the Rig page."""
    import types

    from app.nodes.backends import replay
    from app.nodes.protocol import encode_skeletons

    store = NodeStore(tmp_path / "recordings")
    w = store.create_part("R1")
    for k in range(5):
        w.append(k * DT, "skeleton", encode_skeletons(k, k * DT, np.zeros((1, 25, 3)),
                                                      np.full((1, 25), 2)))
    w.close("on_node")
    now = [1000.0]
    monkeypatch.setattr(replay, "time", types.SimpleNamespace(time=lambda: now[0]))
    be = replay.ReplayBackend(tmp_path / "recordings" / "R1")
    be.open()
    agent = NodeAgent("S1", be, "ws://127.0.0.1:1/ws/node", "token", tmp_path / "node")
    assert be.warning_sink == agent._on_backend_warning  # the agent's path to the server
    queued: list[str] = []
    be.warning_sink = queued.append
    now[0] += 120.0  # past the first minute, in which starting up may be slow
    frames = be.frames()
    next(frames)
    assert queued == []
    now[0] += 2.0  # the computer stalled for two seconds
    next(frames)
    next(frames)
    assert len(queued) == 1 and "runs 2.0 s behind its recorded pace" in queued[0]
    frames.close()
