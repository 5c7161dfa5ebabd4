"""Recording faults with real server and node processes over loopback websockets.

One recording on four nodes meets, at once: a second start, a node's clock stepped by
NTP, a node killed (SIGKILL) and restarted while it runs, a node whose websocket is cut
(a TCP proxy between it and the server drops every connection), a node whose disk fills
up (a 16 KiB tmpfs, when this runs as root), and a node that joins after the start. The
restarted node records again into its part, the late one from when it joined.
Then: stop, stop again, stop an unknown recording, delete it while it is transferred.
Every frame a node wrote must end on the server byte-identical, and each part must say
what happened to it.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import signal
import socket
import threading
import urllib.error
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.nodes.store import NodeStore
from app.server.storage import read_part_skeleton
from tests.app.data.test_record_flow import setup_session
from tests.integration.conftest import Rig, wait_for
from tests.tmpfs import tmpfs_if_possible

pytestmark = pytest.mark.slow


class CuttableProxy:
    """A loopback TCP proxy whose connections the test can drop (a network failure
    between one node and the server, the server itself staying up)."""

    def __init__(self, upstream_port: int) -> None:
        self.upstream = upstream_port
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = int(self.listener.getsockname()[1])
        self.conns: list[socket.socket] = []
        self.lock = threading.Lock()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                down, _ = self.listener.accept()
                up = socket.create_connection(("127.0.0.1", self.upstream))
            except OSError:
                return
            with self.lock:
                self.conns += [down, up]
            for a, b in ((down, up), (up, down)):
                threading.Thread(target=self._pump, args=(a, b), daemon=True).start()

    @staticmethod
    def _pump(src: socket.socket, dst: socket.socket) -> None:
        with contextlib.suppress(OSError):
            while data := src.recv(65536):
                dst.sendall(data)
        for s in (src, dst):
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)

    def cut(self) -> None:
        """Drop every connection (the node reconnects through the proxy)."""
        with self.lock:
            conns, self.conns = self.conns, []
        for s in conns:
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)
            s.close()

    def close(self) -> None:
        self.listener.close()
        self.cut()


@pytest.fixture
def tiny_node_disk(tmp_path: Path) -> Iterator[Path | None]:
    """The recordings folder of node S3 on a 16 KiB tmpfs (None when it cannot be
    mounted: the disk-full part of the test is skipped then)."""
    with tmpfs_if_possible(tmp_path / "nodes" / "S3" / "recordings", "16k") as folder:
        yield folder


def _http_error(fn: Any) -> tuple[int, str]:
    try:
        fn()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read().decode()
    raise AssertionError("expected an HTTP error")


def _parts(rig: Rig, rec_id: str) -> dict[str, dict[str, Any]]:
    return {p["node_id"]: p for p in rig.api(f"/api/recordings/{rec_id}")["parts"]}


def _sha(path: Path) -> bytes:
    return hashlib.sha256(path.read_bytes()).digest()


@pytest.mark.timeout(180)
def test_one_recording_through_node_faults(make_rig: Any, tiny_node_disk: Path | None
                                           ) -> None:
    rig: Rig = make_rig({"GAITRIG_TEST_CHUNK_SIZE": "1024",
                         "GAITRIG_TEST_CHUNK_DELAY_S": "0.05"})
    proxy = CuttableProxy(rig.port)
    try:
        _run(rig, proxy, tiny_node_disk)
    finally:
        proxy.close()


def _run(rig: Rig, proxy: CuttableProxy, tiny_disk: Path | None) -> None:
    nodes = ["S1", "S2", "S3"] if tiny_disk is not None else ["S1", "S2"]
    killed = rig.start_node("S1")
    step_file = rig.tmp / "S2-clock-step"
    rig._spawn("S2", ["node", "--id", "S2", "--server", f"ws://127.0.0.1:{proxy.port}",
                      "--data-dir", str(rig.node_dir("S2")), "--no-images"],
               env={**rig.env, "GAITRIG_TEST_CLOCK_STEP_FILE": str(step_file)})
    if tiny_disk is not None:
        rig.start_node("S3")
    rig.wait_online(nodes, timeout=60)
    ids = setup_session(rig)
    rec_id = rig.api(f"/api/sessions/{ids['session']['id']}/recordings", {"label": "walk"})["id"]
    code, msg = _http_error(lambda: rig.api("/api/recordings", {}))
    assert code == 409 and "already running" in msg
    rig.start_node("S4")  # joins after the start: recorded from then on
    wait_for(lambda: all(_parts(rig, rec_id)[n]["n_frames"] > 15 for n in nodes), 30,
             "every node recording")
    # NTP steps S2's system clock 0.4 s ahead: its recorded times must stay continuous
    step_file.write_text("0.4")

    # S1 killed: its part is incomplete and says so; restarted, it reports what it kept
    os.kill(killed.pid, signal.SIGKILL)
    killed.wait()
    # S2's websocket dropped: incomplete, then recording again once it reconnected
    proxy.cut()
    p = wait_for(lambda: (ps := _parts(rig, rec_id))["S1"]["state"] == "incomplete" and
                 ps["S2"]["state"] == "recording" and "kept recording" in
                 (ps["S2"]["reason"] or "") and ps, 30, "S1 gone, S2 back")
    assert "node S1 disconnected at" in p["S1"]["reason"]
    assert p["S2"]["reason"].startswith("node S2 disconnected at")
    rig.start_node("S1", name="S1-again")  # back while the recording runs: records again
    if tiny_disk is not None:  # S3's disk is full by now: it stopped, with the reason
        p = wait_for(lambda: (ps := _parts(rig, rec_id))["S3"]["state"] == "incomplete" and
                     ps, 30, "S3's full disk")
        assert p["S3"]["reason"].startswith("node S3's disk is full; recording stopped")
        assert p["S3"]["n_frames"] > 15
    p = wait_for(lambda: "recording again" in ((ps := _parts(rig, rec_id))["S1"]["reason"]
                                               or "") and ps["S1"]["state"] == "recording"
                 and ps, 30, "S1 recording again")
    assert "recovered" in p["S1"]["reason"] and p["S1"]["n_frames"] > 15
    n_before = p["S1"]["n_frames"]
    p = wait_for(lambda: (ps := _parts(rig, rec_id))["S1"]["n_frames"] > n_before + 15 and
                 ps["S4"]["n_frames"] > 15 and ps, 30, "S1 and S4 recording")
    assert "joined" in p["S4"]["reason"] and "after the start" in p["S4"]["reason"]

    rec = rig.api(f"/api/recordings/{rec_id}/stop", method="POST")
    assert {q["node_id"] for q in rec["parts"]} == {*nodes, "S4"}
    code, msg = _http_error(lambda: rig.api(f"/api/recordings/{rec_id}/stop", method="POST"))
    assert code == 409 and "already stopped" in msg
    code, msg = _http_error(lambda: rig.api("/api/recordings/R-none/stop", method="POST"))
    assert code == 404

    # pulled on their own (slowed down: 1 kB chunks, 50 ms each); a deletion while they
    # are transferred is refused
    wait_for(lambda: any(q["state"] == "transferring" for q in _parts(rig, rec_id).values()),
             30, "a transfer under way", step=0.02)
    code, msg = _http_error(lambda: rig.api(f"/api/storage/recordings/{rec_id}/delete",
                                            {"confirm": "P001"}))
    assert code == 409 and "being transferred" in msg, msg

    def settled() -> dict[str, dict[str, Any]] | None:
        ps = _parts(rig, rec_id)
        return ps if all(q["on_server"] for q in ps.values()) else None

    ps = wait_for(settled, 60, "every part on the server")
    # the database follows the live state twice a second
    r = wait_for(lambda: (x := rig.api(f"/api/storage/recordings/{rec_id}"))["state"] !=
                 "transferring" and x, 10, "the stored state")
    assert r["state"] == "incomplete"
    assert "S1: node S1 was restarted during the recording:" in r["reason"], r["reason"]
    assert ps["S2"]["state"] == "complete"
    # S2 recorded through the outage: the whole interval
    assert ps["S2"]["t_first"] - rec["t_start"] < 0.05
    assert abs(ps["S2"]["t_last"] - rec["t_stop"]) < 0.05
    if tiny_disk is not None:
        assert ps["S3"]["state"] == "incomplete" and "S3: node S3's disk is full" in r["reason"]
    # S1: before its crash and after its restart, on the server clock, the gap between
    s1 = read_part_skeleton(rig.tmp / "server" / "recordings" / rec_id / "S1").times
    assert len(s1) == ps["S1"]["n_frames"] and np.all(np.diff(s1) > 0)
    assert s1[0] - rec["t_start"] < 0.05 and abs(s1[-1] - rec["t_stop"]) < 0.1
    assert np.max(np.diff(s1)) > 0.5  # the restart
    # S4 joined late: complete from then on
    assert ps["S4"]["state"] == "complete" and ps["S4"]["t_first"] > rec["t_start"] + 0.5
    assert abs(ps["S4"]["t_last"] - rec["t_stop"]) < 0.1
    for n in [*nodes, "S4"]:  # what each node wrote is on the server, byte for byte
        server = rig.tmp / "server" / "recordings" / rec_id / n
        node = rig.node_dir(n) / "recordings" / rec_id
        assert not (server / ".incoming").exists()
        assert _sha(server / "frames.bin") == _sha(node / "frames.bin"), n
        assert _sha(server / "meta.json") == _sha(node / "meta.json"), n
    # S2's clock step is in none of its recorded times (no jump, none dropped)
    ts = [float(h["t"]) for h, _ in NodeStore(rig.node_dir("S2") / "recordings").read(rec_id)
          if h["kind"] == "skeleton"]
    assert max(np.diff(ts)) < 0.2 and len(ts) == ps["S2"]["n_frames"]
    assert "clock stepped by +0.4" in rig.log_text("S2")
