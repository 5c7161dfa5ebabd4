"""A node announces its cameras' lenses after the welcome (protocol revision 3,
``sensor_lens``), so the live view is right before any calibration: real sim node
processes, a real server, loopback; and nodes of the older revisions, bad lenses and a
server of revision 2 next to it."""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path

import numpy as np
import pytest
from websockets.asyncio.client import connect

from app.nodes.protocol import CameraLens, Hello, SensorInfo, SensorLens, dump
from tests.app.live.test_cloud_lens import LENS, LENS_NODES, live_floor_of_lens_nodes
from tests.integration.conftest import TOKEN, Rig, free_port, wait_for

pytestmark = pytest.mark.slow

K = [[365.0, 0.0, 255.5], [0.0, 365.0, 211.5], [0.0, 0.0, 1.0]]


def test_live_cloud_of_lens_nodes_without_calibration_is_flat(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Two simulated node processes rendering their depth through a lens, NO calibration
    (the simulator's poses): the lens they announced puts the floor the server draws flat,
    by the measure of the calibrated case (tests/app/live/test_cloud_lens.py: |z| median
    < 3 mm, 99th percentile < 1 cm; pinhole, as before nodes announced a lens, is 13 mm
    and 57 mm there), and the Rig page's node list says where the lens came from."""
    from app.server.calibration import active_result

    z, lens_of, nodes = live_floor_of_lens_nodes(tmp_path, monkeypatch)
    assert active_result(tmp_path) is None  # no calibration was involved
    assert lens_of == {sid: pytest.approx(LENS) for sid in LENS_NODES}  # from the start
    assert np.median(z) < 0.003 and np.percentile(z, 99) < 0.01, np.percentile(z, [50, 95, 99])
    lenses = {n["id"]: n["lens"] for n in nodes}
    for sid in LENS_NODES:
        assert lenses[sid]["source"] == "simulator"  # type: ignore[index]
        assert lenses[sid]["depth_dist"] == pytest.approx(LENS)  # type: ignore[index]


def test_older_nodes_and_bad_lenses_keep_their_connection(make_rig: object) -> None:
    """A revision-2 node (it never announces a lens) is listed with none; a lens that is
    malformed or does not describe the hello's camera is refused with a warning and an
    ``error`` answer, the connection stays, and a good one after it is taken."""
    rig: Rig = make_rig()  # type: ignore[operator]
    url = f"ws://127.0.0.1:{rig.port}/ws/node"
    sensor = SensorInfo(depth_size=(512, 424), depth_K=K)

    async def old_node() -> None:
        async with connect(url, open_timeout=5) as ws:
            await ws.send(dump(Hello(node_id="R2", token=TOKEN, protocol=2, sensor=sensor)))
            assert json.loads(await asyncio.wait_for(ws.recv(), 5))["type"] == "welcome"
            wait_for(lambda: rig.nodes()["R2"]["connected"], 10, "the old node listed")
            n = rig.nodes()["R2"]
            assert n["lens"] is None and n["rejected_messages"] == 0

    asyncio.run(old_node())

    good = SensorLens(source="factory calibration",
                      depth=CameraLens(size=(512, 424), K=K, dist=list(LENS)))
    other_camera = good.model_copy(update={"depth": CameraLens(size=(640, 576), K=K)})
    malformed = json.dumps({**json.loads(dump(good)),
                            "depth": {"size": [512, 424], "K": K, "dist": [0.1, 0.2, 0.3]}})

    async def new_node() -> None:
        async with connect(url, open_timeout=5) as ws:
            await ws.send(dump(Hello(node_id="N3", token=TOKEN, sensor=sensor)))
            welcome = json.loads(await asyncio.wait_for(ws.recv(), 5))
            assert "sensor_lens" in welcome["accepts"]
            for k, bad in enumerate((dump(other_camera), malformed), start=1):
                await ws.send(bad)
                while True:  # pings come first
                    m = json.loads(await asyncio.wait_for(ws.recv(), 5))
                    if m["type"] == "error":
                        break
                assert ("sensor lens refused" in m["reason"] if k == 1
                        else "4, 5, 8, 12 or 14" in m["reason"]), m
                n = rig.nodes()["N3"]
                assert n["connected"] and n["rejected_messages"] == k and n["lens"] is None
            await ws.send(dump(good))
            n = wait_for(lambda: rig.nodes()["N3"]["lens"] and rig.nodes()["N3"], 10,
                         "the lens taken")
            assert n["lens"] == {"source": "factory calibration",
                                 "depth_dist": pytest.approx(LENS), "color_dist": None}
            assert n["rejected_messages"] == 2 and not ws.close_code

    asyncio.run(new_node())
    log = rig.log_text("server")
    assert "sensor lens refused: the depth lens is for 640×576 images" in log
    assert "N3 lens (factory calibration)" in log


def test_a_node_announces_its_lens_only_to_a_server_that_takes_it(tmp_path: Path) -> None:
    """A sim node process (revision 3) and a server of revision 2 (its welcome accepts
    ``warning`` only; it would answer a ``sensor_lens`` with an error): the node sends no
    lens. Reconnected to one of revision 3, it announces its depth lens right after the
    welcome."""
    import os
    import subprocess
    import sys

    from websockets.asyncio.server import serve

    seen: list[list[str]] = []  # message types per connection, in order
    done: list[int] = []

    async def handler(ws: object) -> None:
        hello = json.loads(await ws.recv())  # type: ignore[attr-defined]
        assert hello["type"] == "hello" and hello["protocol"] >= 3
        accepts = ["warning"] if not seen else ["warning", "sensor_lens"]
        types: list[str] = []
        seen.append(types)
        await ws.send(json.dumps({"v": 1, "type": "welcome",  # type: ignore[attr-defined]
                                  "server_time": time.time(), "ping_interval_s": 0.1,
                                  "accepts": accepts}))
        # three status rounds (one a second): a lens the node sends, it sends by then
        t_end = time.monotonic() + 30  # only a bound for a broken node
        while types.count("status") < 3 and time.monotonic() < t_end:
            try:
                raw = await asyncio.wait_for(ws.recv(), 0.5)  # type: ignore[attr-defined]
            except TimeoutError:
                continue
            if isinstance(raw, str):
                m = json.loads(raw)
                types.append(m["type"])
                if m["type"] == "sensor_lens":
                    types.append(json.dumps(m))
        done.append(len(seen))  # then close: the node reconnects

    port = free_port()
    env = {**os.environ, "GAITRIG_NODE_TOKEN": TOKEN, "PYTHONUNBUFFERED": "1",
           "GAITRIG_NODE_MIN_FREE_GB": "0", "GAITRIG_NODE_MIN_FREE_PERCENT": "0",
           "GAITRIG_TEST_SIM_DEPTH_DIST": ",".join(str(x) for x in LENS)}

    async def run() -> None:
        async with serve(handler, "127.0.0.1", port):
            deadline = time.monotonic() + 90
            while len(done) < 2 and time.monotonic() < deadline:
                assert node.poll() is None
                await asyncio.sleep(0.2)

    log = tmp_path / "S3.log"
    with open(log, "wb") as f:
        node = subprocess.Popen(
            [sys.executable, "-m", "app.cli", "node", "--id", "S3", "--server",
             f"ws://127.0.0.1:{port}", "--data-dir", str(tmp_path / "S3"), "--no-images"],
            env=env, stdout=f, stderr=subprocess.STDOUT)
    try:
        asyncio.run(run())
    finally:
        node.terminate()
        try:
            node.wait(timeout=15)
        except subprocess.TimeoutExpired:
            node.kill()
            node.wait()
    assert len(done) >= 2, log.read_text(errors="replace")[-2000:]
    old, new = seen[0], seen[1]
    assert "status" in old and "sensor_lens" not in old and "error" not in old, old
    assert new.count("sensor_lens") == 1 and new[0] == "sensor_lens", new
    lens = json.loads(new[1])
    assert lens["source"] == "simulator" and lens["depth"]["dist"] == pytest.approx(LENS)
    assert lens["depth"]["size"] == [512, 424]
