"""Calibration capture over the real node protocol: a server process and simulated node
processes on loopback websockets (colour + depth frames travel as binary ``calib``
messages). Progress, accept/reject, clear errors (a node without images, an offline
node, a second capture while one runs, an unknown capture) and the live bumped-tripod
check."""

from __future__ import annotations

import json
import time
import urllib.error
from typing import Any

import numpy as np

from engine.geometry import pose_error
from engine.sim.rig import default_avenue_rig
from tests.integration.conftest import Rig


def _status(r: Rig, path: str, data: dict[str, Any] | None = None) -> tuple[int, Any]:
    try:
        return 200, r.api(path, data)
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read() or b"{}")


def _wait_job(r: Rig, job_id: int, timeout: float = 240.0) -> dict[str, Any]:
    deadline = time.time() + timeout
    while time.time() < deadline:
        j: dict[str, Any] = r.api(f"/api/calibration/captures/{job_id}")
        if j["state"] not in ("capturing", "computing"):
            return j
        time.sleep(0.1)  # a local server: polled often, the job is seen done at once
    raise AssertionError(f"capture {job_id} still running after {timeout} s")


def test_capture_from_nodes_accept_reject_and_live_check(rig: Rig) -> None:
    rig.start_node("S1", images=True)
    rig.start_node("S2", images=True)
    rig.start_node("S3")  # --no-images: no colour or depth to calibrate with
    rig.wait_online(["S1", "S2", "S3"], timeout=90)

    code, body = _status(rig, "/api/calibration/live-check", {"frames": 3})
    assert code == 400 and "no calibration yet" in body["detail"]
    code, body = _status(rig, "/api/calibration/capture",
                         {"frames": 3, "size_m": 0.4, "nodes": ["S1", "S9"]})
    assert code == 400 and "S9" in body["detail"] and "not connected" in body["detail"]

    # S3 cannot send frames: the capture fails naming it and why
    job = rig.api("/api/calibration/capture", {"frames": 3, "size_m": 0.4})
    assert job["state"] == "capturing" and sorted(job["nodes"]) == ["S1", "S2", "S3"]
    code, body = _status(rig, "/api/calibration/capture", {"frames": 3, "size_m": 0.4})
    assert code == 409 and "still" in body["detail"]
    j = _wait_job(rig, job["id"])
    assert j["state"] == "failed", j
    assert "S3" in j["message"] and "--no-images" in j["message"]
    assert j["nodes"]["S1"]["received"] == 3 and j["nodes"]["S2"]["received"] == 3

    # S1 + S2 share marker 1: calibrated from their frames, nothing saved until accepted
    job = rig.api("/api/calibration/capture", {"frames": 4, "size_m": 0.4,
                                               "nodes": ["S1", "S2"], "ids": "1-8"})
    j = _wait_job(rig, job["id"])
    assert j["state"] == "done", j
    doc = j["result"]
    truth = default_avenue_rig(0)
    for sid in ("S1", "S2"):
        dt, dr = pose_error(np.asarray(doc["T_world_sensor"][sid]),
                            truth.sensor(sid).T_world_sensor)
        assert dt < 0.01 and np.degrees(dr) < 0.5, (sid, dt, np.degrees(dr))
    assert sorted(r["sensor"] for r in doc["meta"]["icp"]) == ["S1", "S2"]
    assert {(e["sensor"], e["marker"]) for e in doc["edges"]} >= {("S1", 1), ("S2", 1)}
    assert rig.api("/api/calibration") == []
    assert rig.api(f"/api/calibration/captures/{job['id']}/reject", {}) == {
        "rejected": job["id"]}
    code, body = _status(rig, f"/api/calibration/captures/{job['id']}/accept", {})
    assert code == 400 and "rejected" in body["detail"]
    assert rig.api("/api/calibration") == []

    job = rig.api("/api/calibration/capture", {"frames": 4, "size_m": 0.4,
                                               "nodes": ["S1", "S2"]})
    assert _wait_job(rig, job["id"])["state"] == "done"
    acc = rig.api(f"/api/calibration/captures/{job['id']}/accept", {})
    assert acc["version"] == 1 and acc["applied_to"] == ["S1", "S2"]
    assert rig.api("/api/calibration/active")["meta"]["source"].startswith("capture")
    code, _ = _status(rig, "/api/calibration/captures/9999")
    assert code == 404

    # live check: nothing moved; S3 has no images and is reported, not crashed on
    assert rig.api("/api/calibration/live-check")["checked"] is False
    chk = rig.api("/api/calibration/live-check", {"frames": 3})
    j = _wait_job(rig, chk["id"])
    assert j["state"] == "done", j
    by = {c["sensor"]: c for c in j["checks"]}
    assert by["S1"]["status"] == "ok" and by["S2"]["status"] == "ok", by
    assert by["S1"]["moved_mm"] < 10 and by["S2"]["rotated_deg"] < 0.5
    assert by["S3"]["status"] == "unknown" and "--no-images" in by["S3"]["reason"]
    last = rig.api("/api/calibration/live-check")
    assert last["checked"] and last["moved"] == [] and last["id"] == chk["id"]
