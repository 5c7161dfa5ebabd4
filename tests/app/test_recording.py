"""Recording orchestration: commands per node, part states, persistence."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

from app.nodes.protocol import PartInfo, SensorInfo
from app.server.recording import RecordingManager
from app.server.registry import NodeRegistry
from engine.errors import InputError


def _registry(sent: dict[str, list[dict[str, object]]], offsets: dict[str, float]
              ) -> NodeRegistry:
    reg = NodeRegistry()
    for nid, off in offsets.items():
        sent[nid] = []

        async def send(text: str, nid: str = nid) -> None:
            sent[nid].append(json.loads(text))

        s = reg.connect(nid, "sim", SensorInfo(), send, restarted=True)
        for k in range(20):  # symmetric exchanges: the estimate is exact
            t1 = 1000.0 + 0.1 * k
            s.clock.add(t1, t1 + off + 1e-4, t1 + off + 1.5e-4, t1 + 2.5e-4)
    return reg


def test_start_stop_parts_and_persistence(tmp_path: Path) -> None:
    sent: dict[str, list[dict[str, object]]] = {}
    offsets = {"S1": 0.5, "S2": -0.25}

    async def scenario() -> str:
        reg = _registry(sent, offsets)
        mgr = RecordingManager(reg, tmp_path, start_margin_s=0.2)
        rec = mgr.start()
        with pytest.raises(InputError, match="already running"):
            mgr.start()
        await asyncio.sleep(0.01)
        for nid, off in offsets.items():
            cmd = sent[nid][0]
            assert cmd["type"] == "rec_start" and cmd["rec_id"] == rec.id
            assert cmd["t_start_local"] == pytest.approx(rec.t_start + off, abs=1e-6)
        mgr.on_part("S1", PartInfo(rec_id=rec.id, state="recording", n_frames=3))
        mgr.on_part("S2", PartInfo(rec_id=rec.id, state="recording"))
        assert rec.state == "recording"
        mgr.stop(rec.id)
        await asyncio.sleep(0.01)
        assert sent["S1"][1]["type"] == "rec_stop"
        assert rec.state == "stopping"
        t_first = rec.t_start + 0.5 + 0.01  # S1's local time of a frame 10 ms after start
        mgr.on_part("S1", PartInfo(rec_id=rec.id, state="on_node", n_frames=90,
                                   t_first=t_first, t_last=t_first + 3.0))
        reg.disconnect("S2")
        mgr.on_disconnect("S2")
        assert rec.parts["S1"].t_first == pytest.approx(rec.t_start + 0.01, abs=1e-6)
        assert rec.parts["S2"].state == "incomplete" and "S2 disconnected" in (
            rec.parts["S2"].reason or "")
        assert rec.state == "incomplete"
        # a late on_node for a node that had dropped out (network blip) completes it
        mgr.on_part("S2", PartInfo(rec_id=rec.id, state="on_node", n_frames=88))
        assert rec.state == "on_nodes"
        return rec.id

    rec_id = asyncio.run(scenario())
    again = RecordingManager(NodeRegistry(), tmp_path)
    assert again.recordings[rec_id].state == "on_nodes"
    assert again.recordings[rec_id].parts["S1"].n_frames == 90


def test_server_crash_during_recording_marks_parts(tmp_path: Path) -> None:
    sent: dict[str, list[dict[str, object]]] = {}

    async def scenario() -> str:
        mgr = RecordingManager(_registry(sent, {"S1": 0.0}), tmp_path)
        return mgr.start().id

    rec_id = asyncio.run(scenario())
    again = RecordingManager(NodeRegistry(), tmp_path)
    rec = again.recordings[rec_id]
    assert rec.state == "incomplete"
    assert "server restarted" in (rec.parts["S1"].reason or "")


def test_nodes_without_clock_cannot_record(tmp_path: Path) -> None:
    reg = NodeRegistry()

    async def send(text: str) -> None:
        return None

    reg.connect("S1", "sim", SensorInfo(), send, restarted=True)
    with pytest.raises(InputError, match="measured clock"):
        RecordingManager(reg, tmp_path).start()


def test_a_failing_save_neither_fails_a_start_nor_a_node_message(tmp_path: Path) -> None:
    sent: dict[str, list[dict[str, object]]] = {}
    (tmp_path / "recordings.tmp").mkdir()  # the atomic save's temporary file cannot be made

    async def scenario() -> None:
        mgr = RecordingManager(_registry(sent, {"S1": 0.0}), tmp_path)
        rec = mgr.start()  # the commands are out: the start must not fail now
        mgr.on_part("S1", PartInfo(rec_id=rec.id, state="recording", n_frames=3))
        assert rec.parts["S1"].state == "recording"
        assert "could not save its recording list" in mgr.to_dict(rec)["save_error"]
        (tmp_path / "recordings.tmp").rmdir()  # space again: the next change saves it all
        mgr.stop(rec.id)
        assert mgr.save_error is None and mgr.to_dict(rec)["save_error"] is None
        assert RecordingManager(NodeRegistry(), tmp_path).recordings[rec.id].t_stop

    asyncio.run(scenario())


def test_nodes_back_or_new_during_a_recording_record(tmp_path: Path) -> None:
    sent: dict[str, list[dict[str, object]]] = {}

    async def scenario() -> None:
        reg = _registry(sent, {"S1": 0.5, "S2": 0.0})
        mgr = RecordingManager(reg, tmp_path, start_margin_s=0.2)
        rec = mgr.start()
        await asyncio.sleep(0.01)
        for nid in ("S1", "S2"):
            mgr.on_part(nid, PartInfo(rec_id=rec.id, state="recording", n_frames=30))
        send2 = reg.nodes["S2"].send
        # S1 crashes; S2's network blips (it keeps recording)
        for nid in ("S1", "S2"):
            reg.disconnect(nid)
            mgr.on_disconnect(nid)
        assert mgr.rejoin() == []
        # S1 restarted: its clock now counts from another origin (offset 100.5 s)
        new = _registry(sent, {"S1": 100.5, "S3": -1.0})
        for nid in ("S1", "S3"):  # S3 was not there at the start
            reg.nodes[nid] = new.nodes[nid]
        assert send2 is not None
        reg.connect("S2", "sim", SensorInfo(), send2, restarted=False)
        mgr.on_part("S2", PartInfo(rec_id=rec.id, state="recording", n_frames=40),
                    from_hello=True)
        mgr.on_part("S1", PartInfo(rec_id=rec.id, state="incomplete", n_frames=30,
                                   reason="node stopped while recording"), from_hello=True)
        assert mgr.rejoin() == []  # just connected: their hellos may not be in yet
        for nid in ("S1", "S2", "S3"):
            reg.nodes[nid].connected_at = reg.nodes[nid].connected_at - 2.0  # type: ignore[operator]
        assert mgr.rejoin() == ["S1", "S3"]
        await asyncio.sleep(0.01)
        resume, late = sent["S1"][-1], sent["S3"][-1]
        assert resume["type"] == "rec_start" and resume["resume"] is True
        t = resume["t_start_server"]
        assert resume["t_start_local"] == pytest.approx(t + 100.5, abs=1e-6)  # type: ignore[operator]
        # frames of the new clock + rebase_s = the part's first clock (offset 0.5)
        assert resume["rebase_s"] == pytest.approx(-100.0, abs=1e-6)
        assert rec.parts["S1"].state == "pending"
        assert "recording again from" in (rec.parts["S1"].reason or "")
        assert late["resume"] is False and late["t_start_server"] > rec.t_start  # type: ignore[operator]
        assert "S3 joined" in (rec.parts["S3"].reason or "")
        assert rec.parts["S2"].state == "recording" and len(sent["S2"]) == 1  # start only
        assert mgr.rejoin() == []  # once per drop
        mgr.stop(rec.id)
        assert mgr.rejoin() == []  # nothing runs

    asyncio.run(scenario())
