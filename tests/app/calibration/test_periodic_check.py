"""Periodic bumped-tripod check: the server re-detects the markers by itself every
``calibration_check_interval_s`` and reports a moved sensor on ``GET
/api/calibration/live-check`` without anyone asking. Integration test over real node
processes (one node's simulated tripod really moved after the calibration), plus unit
tests of when the check may run and how its findings are kept."""

from __future__ import annotations

import asyncio
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from app.server.calibration import CaptureJob, CaptureManager, calibration_dir
from engine.calibration.store import save_version
from engine.errors import InputError
from tests.app.calibration.sim_truth import (
    BUMP_DEG,
    BUMP_M,
    bumped_rig_file,
    truth_calibration,
)
from tests.integration.conftest import Rig, wait_for


def _periodic(r: Rig, state: str, text: str) -> dict[str, Any] | None:
    d: dict[str, Any] = r.api("/api/calibration/live-check")
    p = d["periodic"]
    return d if p["state"] == state and text in p["reason"] else None


def test_periodic_check_reports_a_bumped_tripod_without_a_request(tmp_path: Path) -> None:
    r = Rig(tmp_path, {"GAITRIG_CALIBRATION_CHECK_INTERVAL_S": "0.5"})
    try:
        d = wait_for(lambda: _periodic(r, "skipped", "no calibration yet"), 120,
                     "the periodic check to report that nothing is calibrated")
        assert d["periodic"]["enabled"] and d["periodic"]["interval_s"] == 0.5
        assert d["checked"] is False and d["warnings"] == []

        save_version(truth_calibration(["S1", "S2"]), calibration_dir(tmp_path / "server"))
        wait_for(lambda: _periodic(r, "skipped", "sensors S1, S2 of the calibration not connected"),
                 120, "the periodic check to wait for the calibrated sensors")

        # S2's tripod was bumped after the calibration: its simulated camera really moved
        rig_file = bumped_rig_file(tmp_path / "bumped.toml", "S2")
        r.start_node("S1", images=True)
        r.start_node("S2", "--rig", str(rig_file), images=True)
        r.wait_online(["S1", "S2"], timeout=120)

        # no POST: the server's own check finds it
        last = wait_for(lambda: (d := r.api("/api/calibration/live-check"))["warnings"] and d,
                        600, "the periodic check to report the moved sensor", step=0.2)
        assert [w["sensor"] for w in last["warnings"]] == ["S2"], last
        w = last["warnings"][0]
        assert w["moved_mm"] == pytest.approx(BUMP_M * 1000, abs=5), w
        assert w["rotated_deg"] == pytest.approx(BUMP_DEG, abs=0.25), w
        assert w["calibration_version"] == 1 and w["calibration_created"] > 0
        assert last["checked"] and last["trigger"] == "periodic" and last["frames"] == 5
        assert last["moved"] == ["S2"], last
        by = {c["sensor"]: c for c in last["checks"]}
        assert by["S1"]["status"] == "ok" and by["S2"]["status"] == "moved", by
        assert "recalibrate" in by["S2"]["reason"]

        # a recording holds the periodic check back; the warning stays meanwhile
        rec = r.api("/api/recordings", {})
        d = wait_for(lambda: _periodic(r, "skipped", f"recording {rec['id']}"), 300,
                     "the periodic check to wait for the recording", step=0.1)
        assert [x["sensor"] for x in d["warnings"]] == ["S2"]
        r.api(f"/api/recordings/{rec['id']}/stop", method="POST")

        # recalibrating (a new active version) supersedes the old finding
        save_version(truth_calibration(["S1", "S2"]), calibration_dir(tmp_path / "server"))
        d = r.api("/api/calibration/live-check")
        assert d["warnings"] == [] and d["checked"] is False
        assert d["superseded"]["calibration_version"] == 1
        assert "Traceback" not in r.log_text("server")
    finally:
        r.close()


# ------------------------------------------------------------------------- unit tests


def _session(connected: bool = True) -> Any:
    async def send(_text: str) -> None:
        return None

    return SimpleNamespace(connected=connected, send=send if connected else None)


def _hub(nodes: dict[str, Any], recordings: dict[str, Any] | None = None,
         running: set[str] | None = None) -> Any:
    return SimpleNamespace(
        registry=SimpleNamespace(nodes=nodes), binary_listeners={},
        recordings=SimpleNamespace(recordings=recordings or {}),
        transfers=SimpleNamespace(running_parts=lambda rec_id: set(running or ())))


def test_a_capture_names_the_nodes_not_connected_in_the_right_number(tmp_path: Path
                                                                      ) -> None:
    nodes = {"S1": _session(), "S2": _session(False), "S3": _session(False)}
    mgr = CaptureManager(_hub(nodes), tmp_path)
    with pytest.raises(InputError, match=r"^node S2 is not connected$"):
        asyncio.run(mgr.start("calibrate", 5, {1: 0.2}, nodes=["S1", "S2"]))
    with pytest.raises(InputError, match=r"^nodes S2, S3 are not connected$"):
        asyncio.run(mgr.start("calibrate", 5, {1: 0.2}, nodes=["S3", "S2"]))
    assert mgr.jobs == {}  # refused before any job started


def test_periodic_blocker_reasons(tmp_path: Path) -> None:
    nodes = {"S1": _session(), "S2": _session(False)}
    mgr = CaptureManager(_hub(nodes), tmp_path)
    assert mgr.periodic_blocker() == ("no calibration yet", [])
    save_version(truth_calibration(["S1", "S2"]), calibration_dir(tmp_path))
    reason, want = mgr.periodic_blocker()
    assert reason is not None and reason.startswith("sensor S2 of the calibration not connected")
    assert want == ["S1", "S2"]
    nodes["S2"] = _session()
    assert mgr.periodic_blocker() == (None, ["S1", "S2"])
    for state in ("recording", "stopping", "transferring"):
        busy = CaptureManager(_hub(nodes, {"r1": SimpleNamespace(id="r1", state=state)}),
                              tmp_path)
        reason, _ = busy.periodic_blocker()
        assert reason is not None and f"recording r1 is {state}" in reason
    done = SimpleNamespace(id="r0", state="on_nodes")
    assert CaptureManager(_hub(nodes, {"r0": done}), tmp_path).periodic_blocker()[0] is None
    # a transfer of an older recording still pulls data from the nodes
    pulling = CaptureManager(_hub(nodes, {"r0": done}, running={"S1"}), tmp_path)
    assert "recording r0" in (pulling.periodic_blocker()[0] or "")


def test_periodic_check_skips_with_a_reason_instead_of_failing(tmp_path: Path) -> None:
    mgr = CaptureManager(_hub({"S1": _session(False)}), tmp_path)
    save_version(truth_calibration(["S1"]), calibration_dir(tmp_path))
    assert asyncio.run(mgr.periodic_check()) is None
    assert mgr.periodic["state"] == "skipped" and "S1" in mgr.periodic["reason"]
    assert mgr.last_check is None


def _check_job(mgr: CaptureManager, job_id: int, version: int,
               checks: dict[str, str]) -> CaptureJob:
    job = CaptureJob(job_id, "check", sorted(checks), 5, {}, calibration_version=version,
                     calibration_created=1e9)
    job.checks = [{"sensor": s, "status": st, "moved_mm": 21.0 if st == "moved" else None,
                   "rotated_deg": 0.8 if st == "moved" else None, "reason": ""}
                  for s, st in checks.items()]
    mgr._record_moved(job)
    job.state = "done"
    mgr.last_check = job
    return job


def test_a_moved_sensor_stays_reported_until_seen_back_in_place(tmp_path: Path) -> None:
    mgr = CaptureManager(_hub({}), tmp_path)
    save_version(truth_calibration(["S1", "S2"]), calibration_dir(tmp_path))
    _check_job(mgr, 1, 1, {"S1": "ok", "S2": "moved"})
    v = mgr.live_check_view()
    assert v["checked"] and v["moved"] == ["S2"]
    assert [(w["sensor"], w["moved_mm"], w["check_id"]) for w in v["warnings"]] == [
        ("S2", 21.0, 1)]
    # someone stands on S2's markers: the check cannot tell, the warning stays
    _check_job(mgr, 2, 1, {"S1": "ok", "S2": "unknown"})
    v = mgr.live_check_view()
    assert v["moved"] == [] and [w["sensor"] for w in v["warnings"]] == ["S2"]
    # S2 seen in place again (tripod put back): cleared
    _check_job(mgr, 3, 1, {"S1": "moved", "S2": "ok"})
    assert [w["sensor"] for w in mgr.live_check_view()["warnings"]] == ["S1"]
    # a new calibration: nothing found against it yet
    save_version(truth_calibration(["S1", "S2"]), calibration_dir(tmp_path))
    v = mgr.live_check_view()
    assert v["warnings"] == [] and not v["checked"] and v["superseded"]["id"] == 3
