"""Acceptance tests of the backbone with six real node processes over loopback.

One server (with the test hook that delays every start/stop command by a random
0–500 ms per node) and six sim nodes whose clocks are set to the extremes of the spec
(offsets up to ±0.5 s, drifts up to ±100 ppm). Ground truth for the clocks: the offsets
and drifts passed on the command line, plus the instant each node process took as its
drift reference (reported by the node in ``diag``; the server's estimator never sees it).
"""

from __future__ import annotations

import json
import os
import signal
import time
from collections.abc import Iterator
from typing import Any

import pytest
from websockets.sync.client import connect

from app.nodes.clock import NodeClock
from app.nodes.protocol import Hello, Pong, dump
from app.nodes.store import NodeStore
from tests.integration.conftest import TOKEN, Rig, wait_for

pytestmark = pytest.mark.slow

CLOCKS = {  # offset (s), drift (ppm)
    "S1": (0.5, 100.0), "S2": (-0.5, -100.0), "S3": (0.25, -100.0),
    "S4": (-0.31, 100.0), "S5": (0.0, 50.0), "S6": (0.41, -63.0),
}
MAX_PERIOD = 1.0 / 25.0  # the sensors' frame periods stay within 25–35 Hz
CLOCK_TOL = 1e-3


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    r = Rig(tmp_path_factory.mktemp("rig"), {"GAITRIG_TEST_COMMAND_DELAY_MAX_S": "0.5",
                                                "GAITRIG_RECORD_START_MARGIN_S": "0.05"})
    try:
        for nid, (off, ppm) in CLOCKS.items():
            r.start_node(nid, "--clock-offset", str(off), "--clock-drift-ppm", str(ppm))
        r.wait_online(list(CLOCKS), timeout=90)  # generous: the machine may be loaded
        yield r
    finally:
        r.close()


def true_clock(rig: Rig, nid: str) -> NodeClock:
    off, ppm = CLOCKS[nid]
    diag = rig.nodes()[nid]["diag"]
    return NodeClock(off, ppm * 1e-6, t_ref=diag["clock_t_ref"])


def true_span(rig: Rig, nid: str, rec_id: str, clock: NodeClock) -> tuple[float, float, int]:
    store = NodeStore(rig.node_dir(nid) / "recordings")
    ts = [float(h["t"]) for h, _ in store.read(rec_id) if h["kind"] == "skeleton"]
    assert ts, f"{nid} recorded nothing"
    return clock.to_host(ts[0]), clock.to_host(ts[-1]), len(ts)


def test_clock_offsets_within_1ms_after_10s(rig: Rig) -> None:
    ns = rig.nodes()
    t_conn = max(n["connected_at"] for n in ns.values())
    time.sleep(max(0.0, t_conn + 10.5 - time.time()))
    ns = rig.nodes()
    errs = {}
    for nid in CLOCKS:
        n = ns[nid]
        truth = true_clock(rig, nid).true_offset(n["clock_at"])
        errs[nid] = n["clock_offset_ms"] - truth * 1e3
        assert n["clock_uncertainty_ms"] < 2.0
    assert all(abs(e) < 1.0 for e in errs.values()), f"offset errors (ms): {errs}"


# A closed part may already be on its way to (or on) the server: the data-management
# sync transfers every stopped recording automatically.
CLOSED = {"on_node", "transferring", "complete"}


def _wait_parts(rig: Rig, rec_id: str, want: dict[str, str]) -> dict[str, Any]:
    def done() -> dict[str, Any] | None:
        rec = rig.api(f"/api/recordings/{rec_id}")
        states = {p["node_id"]: p["state"] for p in rec["parts"]}
        ok = all(states.get(k) in (CLOSED if v == "on_node" else {v}) for k, v in want.items())
        return rec if ok else None

    result: dict[str, Any] = wait_for(done, 45, f"parts {want}")
    return result


def test_delayed_commands_record_the_same_interval(rig: Rig) -> None:
    rec = rig.api("/api/recordings", {})
    time.sleep(2.5)
    rec = rig.api(f"/api/recordings/{rec['id']}/stop", method="POST")
    rec = _wait_parts(rig, rec["id"], {nid: "on_node" for nid in CLOCKS})
    assert rec["state"] in ("on_nodes", "transferring", "complete")
    t0, t1 = rec["t_start"], rec["t_stop"]
    for nid in CLOCKS:
        first, last, n = true_span(rig, nid, rec["id"], true_clock(rig, nid))
        assert -CLOCK_TOL <= first - t0 < MAX_PERIOD + CLOCK_TOL, (nid, first - t0)
        assert -CLOCK_TOL <= t1 - last < MAX_PERIOD + CLOCK_TOL, (nid, t1 - last)
        assert n >= (t1 - t0) * 25 - 1
    # the hook really made commands late: some nodes took the start from the ring buffer
    late = [nid for nid in CLOCKS if "from the ring buffer" in rig.log_text(nid)]
    assert late, "no start command arrived late; the delay hook did not act"


def test_kill_9_mid_recording(rig: Rig) -> None:
    rec = rig.api("/api/recordings", {})
    time.sleep(2.5)
    victim = rig.procs["S3"]
    t_kill = time.time()
    os.kill(victim.pid, signal.SIGKILL)
    victim.wait()
    time.sleep(1.5)
    rec = rig.api(f"/api/recordings/{rec['id']}/stop", method="POST")
    others = {nid: "on_node" for nid in CLOCKS if nid != "S3"}
    rec = _wait_parts(rig, rec["id"], {**others, "S3": "incomplete"})
    assert rec["state"] in ("incomplete", "transferring")
    parts = {p["node_id"]: p for p in rec["parts"]}
    assert "disconnected" in parts["S3"]["reason"]
    t0, t1 = rec["t_start"], rec["t_stop"]
    for nid in others:  # the others recorded on, the full interval
        first, last, _ = true_span(rig, nid, rec["id"], true_clock(rig, nid))
        assert -CLOCK_TOL <= first - t0 < MAX_PERIOD + CLOCK_TOL
        assert -CLOCK_TOL <= t1 - last < MAX_PERIOD + CLOCK_TOL
    # restart the killed node: it recovers its part and reports it to the server
    clock_s3 = true_clock(rig, "S3")
    off, ppm = CLOCKS["S3"]
    rig.start_node("S3", "--clock-offset", str(off), "--clock-drift-ppm", str(ppm))
    rig.wait_online(["S3"])
    first, last, _ = true_span(rig, "S3", rec["id"], clock_s3)
    assert -CLOCK_TOL <= first - t0 < MAX_PERIOD + CLOCK_TOL
    assert t_kill - 1.0 <= last <= t_kill, f"S3 lost the last {t_kill - last:.3f} s before the kill"

    def s3_part() -> dict[str, Any] | None:
        r = rig.api(f"/api/recordings/{rec['id']}")
        p = next(p for p in r["parts"] if p["node_id"] == "S3")
        return p if p["state"] == "incomplete" and "recovered" in (p["reason"] or "") else None

    p3 = wait_for(s3_part, 45, "S3's recovered part")
    assert p3["t_last"] == pytest.approx(last, abs=2e-3)  # server converted with its clock model
    meta = json.loads((rig.node_dir("S3") / "recordings" / rec["id"] / "meta.json").read_text())
    assert meta["state"] == "incomplete"


def test_malformed_and_oversized_messages_rejected(rig: Rig) -> None:
    url = f"ws://127.0.0.1:{rig.port}/ws/node"
    with connect(url, max_size=None) as ws:
        ws.send(dump(Hello(node_id="Z9", token=TOKEN, agent_started=1.0)))
        assert json.loads(ws.recv(timeout=5))["type"] == "welcome"

        def until(type_: str) -> dict[str, Any]:
            while True:
                m = json.loads(ws.recv(timeout=5))
                if m["type"] == "ping":
                    ws.send(dump(Pong(seq=m["seq"], t1=m["t1"], t2=time.time(), t3=time.time())))
                if m["type"] == type_:
                    return m

        ws.send("{definitely not json")
        assert "not valid JSON" in until("error")["reason"]
        ws.send(json.dumps({"type": "status", "fps": "fast"}))
        assert "invalid 'status'" in until("error")["reason"]
        ws.send(json.dumps({"type": "error", "reason": "x" * 100_000}))
        assert "exceeds" in until("error")["reason"]
        ws.send(b"GRB\x01" + b"\xff" * 64)
        assert "binary" in until("error")["reason"]
        until("ping")  # the connection is still served
        z9 = rig.nodes()["Z9"]
        assert z9["connected"] and z9["rejected_messages"] == 4
    assert wait_for(lambda: not rig.nodes()["Z9"]["connected"], 5, "Z9 to disconnect")
    log = rig.log_text("server")
    assert "rejected message from node Z9: control message is not valid JSON" in log
    assert "exceeds the 65536-byte limit" in log
    assert all(n["connected"] for nid, n in rig.nodes().items() if nid in CLOCKS)


def test_wrong_token_refused(rig: Rig) -> None:
    # an impostor of a connected node
    p = rig.start_node("S1", token="not-the-token", name="impostor")
    assert p.wait(timeout=90) == 3
    assert "wrong pairing token" in rig.log_text("impostor")
    assert "refused node connection" in rig.log_text("server")
    assert rig.nodes()["S1"]["connected"]  # the genuine S1 is undisturbed
