"""The lens over the real node protocol: a server process and two simulated node
processes on loopback websockets, one rendering its calibration frames through a colour
and a depth lens and sending them (``calib`` header ``color_dist``/``depth_dist``), the
other sending none as older nodes do. Both are calibrated within the usual tolerance and
the result keeps each camera model (the live cloud reads the depth lens from it)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pytest

from engine.geometry import pose_error
from engine.sim.rig import default_avenue_rig
from tests.integration.conftest import Rig

LENS = "-0.08,0.02,0.0005,-0.0003,0"
DEPTH_LENS = "-0.12,0.03,0.0008,-0.0005,0"


def test_node_lens_and_a_node_without_one(rig: Rig) -> None:
    rig._spawn("S1", ["node", "--id", "S1", "--server", f"ws://127.0.0.1:{rig.port}",
                      "--data-dir", str(rig.node_dir("S1"))],
               env={**rig.env, "GAITRIG_TEST_SIM_COLOR_DIST": LENS,
                    "GAITRIG_TEST_SIM_DEPTH_DIST": DEPTH_LENS})
    rig.start_node("S2", images=True)
    rig.wait_online(["S1", "S2"], timeout=90)
    job = rig.api("/api/calibration/capture", {"frames": 3, "size_m": 0.4,
                                               "nodes": ["S1", "S2"], "ids": "1-8"})
    deadline = time.time() + 300
    while True:
        j: dict[str, Any] = rig.api(f"/api/calibration/captures/{job['id']}")
        if j["state"] not in ("capturing", "computing") or time.time() > deadline:
            break
        time.sleep(0.5)
    assert j["state"] == "done", j
    doc = j["result"]
    cams = doc["meta"]["cameras"]
    assert cams["S1"]["color"]["dist"] == pytest.approx([float(x) for x in LENS.split(",")])
    assert cams["S1"]["depth"]["dist"] == pytest.approx(
        [float(x) for x in DEPTH_LENS.split(",")])
    assert cams["S2"]["color"]["dist"] == [] and cams["S2"]["depth"]["dist"] == []
    truth = default_avenue_rig(0)
    for sid in ("S1", "S2"):
        dt, dr = pose_error(np.asarray(doc["T_world_sensor"][sid]),
                            truth.sensor(sid).T_world_sensor)
        assert dt < 0.01 and np.degrees(dr) < 0.5, (sid, dt, np.degrees(dr))
