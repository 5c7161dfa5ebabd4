"""Live images on subscription, reconnection after a server crash, replay as a live node."""

from __future__ import annotations

import time
import urllib.error
import urllib.request
from typing import Any

import cv2
import numpy as np
import pytest

from app.nodes.backends.sim import SimBackend, world_time
from app.nodes.protocol import decode_skeletons
from app.nodes.store import NodeStore
from tests.integration.conftest import Rig, wait_for

pytestmark = pytest.mark.slow


def _image(rig: Rig, node: str, stream: str) -> tuple[bytes, float]:
    req = urllib.request.Request(f"{rig.base}/api/nodes/{node}/images/{stream}",
                                 headers={"Authorization": f"Bearer {rig.token}"})
    with urllib.request.urlopen(req, timeout=5) as r:
        return r.read(), float(r.headers["X-Gaitrig-Time"])


def test_images_reconnect_and_replay(make_rig: object) -> None:
    rig: Rig = make_rig()  # type: ignore[operator]
    rig.start_node("S2", images=True)
    rig.wait_online(["S2"])

    # images on demand: a half-size 16-bit depth PNG
    rig.api("/api/nodes/S2/subscribe", {"streams": ["depth"], "fps": 5, "scale": 0.5,
                                        "format": "png"})
    png, t_server = wait_for(lambda: _image(rig, "S2", "depth"), 60, "a depth image")
    depth: Any = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    assert depth.shape == (212, 256) and depth.dtype == np.uint16
    # ground truth: render the same sensor at the same instant here, downsample alike
    sim = SimBackend("S2", images=True)
    sim.open()
    truth: Any = sim.render(world_time(t_server), ["depth"])["depth"]
    truth = cv2.resize(truth, (256, 212), interpolation=cv2.INTER_NEAREST)
    both = (depth > 0) & (truth > 0)
    assert np.mean((depth > 0) == (truth > 0)) > 0.97
    assert both.sum() > 0.2 * depth.size
    assert np.median(np.abs(depth[both].astype(int) - truth[both])) < 15  # mm (sensor noise)
    rig.api("/api/nodes/S2/subscribe", {"streams": [], "fps": 0})

    # a one-off snapshot: full-size colour and body index of the same instant
    snap = rig.api("/api/nodes/S2/snapshot", {"streams": ["color", "body_index"]})
    assert set(snap["images"]) == {"color", "body_index"}
    bi: Any = cv2.imdecode(np.frombuffer(_image(rig, "S2", "body_index")[0], np.uint8),
                           cv2.IMREAD_UNCHANGED)
    col: Any = cv2.imdecode(np.frombuffer(_image(rig, "S2", "color")[0], np.uint8),
                            cv2.IMREAD_COLOR)
    assert bi.shape == (424, 512) and bi.dtype == np.uint8
    assert col.shape == (360, 640, 3)
    truth_bi = sim.render(world_time(snap["images"]["body_index"]["t"]),
                          ["body_index"])["body_index"]
    assert np.mean(bi == truth_bi) > 0.99

    # a short recording, with every 10th depth frame, to replay later
    rec = rig.api("/api/recordings", {"streams": ["depth"], "image_every": 10})
    time.sleep(1.5)
    rec = rig.api(f"/api/recordings/{rec['id']}/stop", method="POST")
    closed = ("on_nodes", "transferring", "complete")
    state = wait_for(lambda: rig.api(f"/api/recordings/{rec['id']}")["state"] in closed and
                     rig.api(f"/api/recordings/{rec['id']}")["state"], 45,
                     "the recording closed on the node")

    # transfer to the server: verified, byte-identical copy; the state says complete (the
    # data-management sync may already have started it: then the request is a 409)
    if state == "on_nodes":
        try:
            rig.api(f"/api/recordings/{rec['id']}/transfer", {})
        except urllib.error.HTTPError as exc:
            assert exc.code == 409
    done = wait_for(lambda: rig.api(f"/api/recordings/{rec['id']}")["state"] == "complete", 60,
                    "the transfer")
    assert done
    node_part = rig.node_dir("S2") / "recordings" / rec["id"]
    server_part = rig.tmp / "server" / "recordings" / rec["id"] / "S2"
    for name in ("frames.bin", "index.json", "meta.json"):
        assert (server_part / name).read_bytes() == (node_part / name).read_bytes(), name
    assert (server_part / "manifest.json").exists()
    p2 = rig.api(f"/api/recordings/{rec['id']}")["parts"][0]
    assert p2["on_server"] and p2["transfer_progress"] == 1.0

    # the server dies; the node keeps running and reconnects to the new server
    rig.kill_server()
    time.sleep(1.0)
    rig.start_server()
    rig.wait_online(["S2"], timeout=20)
    # frame counts arrive with the node's next status message (1 Hz) after reconnecting
    assert wait_for(lambda: rig.nodes()["S2"]["frames"] > 0, 10, "frames after reconnecting")
    assert rig.api(f"/api/recordings/{rec['id']}")["state"] == "complete"  # persisted

    # replay the part as a live node
    part = rig.node_dir("S2") / "recordings" / rec["id"]
    rig.start_node("R1", "--backend", "replay", "--recording", str(part), "--loop")
    rig.wait_online(["R1"])
    store = NodeStore(rig.node_dir("S2") / "recordings")
    records = list(store.read(rec["id"]))
    recorded = [decode_skeletons(h, p) for h, p in records if h["kind"] == "skeleton"]
    ts = [h["t"] for h, _ in records if h["kind"] == "skeleton"]
    images = [(h, p) for h, p in records if h["kind"] == "image"]
    assert len(images) == (len(ts) + 9) // 10  # frames 1, 11, 21, ...
    assert {h["t"] for h, _ in images} == set(ts[::10])
    d = cv2.imdecode(np.frombuffer(images[0][1], np.uint8), cv2.IMREAD_UNCHANGED)
    assert d is not None and d.shape == (424, 512) and d.dtype == np.uint16
    rate = (len(ts) - 1) / (ts[-1] - ts[0])
    wait_for(lambda: abs(rig.nodes()["R1"]["fps"] / rate - 1) < 0.1, 30,
             f"replay at the recorded rate {rate:.1f} Hz")
    sk = rig.api("/api/nodes/R1/skeleton")
    assert sk["t"] is not None
    pos = np.asarray(sk["positions"], dtype=np.float32).reshape(-1, 25, 3)
    assert any(p.shape == pos.shape and np.array_equal(p, pos, equal_nan=True)
               for p, _ in recorded), "the replayed frame is not one of the recorded frames"


def test_server_crash_during_recording(make_rig: object) -> None:
    rig: Rig = make_rig()  # type: ignore[operator]
    rig.start_node("S5")
    rig.wait_online(["S5"])
    rec = rig.api("/api/recordings", {})
    time.sleep(1.5)
    rig.kill_server()
    time.sleep(1.0)  # the node keeps recording while the server is away
    t_restart = time.time()
    rig.start_server()
    rig.wait_online(["S5"], timeout=20)

    def stopped() -> dict[str, Any] | None:
        r = rig.api(f"/api/recordings/{rec['id']}")
        return r if r["parts"][0]["state"] in ("on_node", "complete") else None

    r = wait_for(stopped, 45, "the node to close its part")
    part = r["parts"][0]
    assert "server restarted" in part["reason"]
    # the node recorded through the outage, up to the stop the new server set
    assert part["t_first"] - r["t_start"] < 0.05
    assert t_restart < r["t_stop"] and abs(part["t_last"] - r["t_stop"]) < 0.05
    # and the server pulls it afterwards on its own: verified, byte-identical
    done = wait_for(lambda: (x := rig.api(f"/api/recordings/{rec['id']}"))["state"] ==
                    "complete" and x, 60, "the transfer after the restart")
    assert done["parts"][0]["on_server"]
    node_part = rig.node_dir("S5") / "recordings" / rec["id"]
    server_part = rig.tmp / "server" / "recordings" / rec["id"] / "S5"
    for name in ("frames.bin", "index.json", "meta.json"):
        assert (server_part / name).read_bytes() == (node_part / name).read_bytes(), name
