"""Node agent recording logic, driven frame by frame (no server, no threads)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from app.nodes.agent import NodeAgent
from app.nodes.backends.base import Backend, Frame
from app.nodes.protocol import RecStart, RecStop, SensorInfo
from app.nodes.store import NodeStore

DT = 1.0 / 30.0


class _Scripted(Backend):
    name = "scripted"

    def open(self) -> SensorInfo:
        return SensorInfo()

    def frames(self) -> Iterator[Frame]:
        return iter(())

    def now(self) -> float:
        return 0.0


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
