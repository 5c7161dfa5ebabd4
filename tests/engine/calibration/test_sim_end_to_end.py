"""``gaitrig calibrate --rig default --json`` end to end on the simulated avenue (one seed,
few frames to stay fast; the five-seed, 30-frame acceptance run is bench/calibration.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from app.cli import main
from engine.calibration.store import load_calibration


def test_calibrate_cli_on_default_avenue(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "cal.json"
    rc = main(["calibrate", "--rig", "default", "--json", "--seed", "1", "--frames", "4",
               "--save", str(out)])
    doc = json.loads(capsys.readouterr().out)
    assert rc == 0
    assert sorted(doc["sensors"]) == ["S1", "S2", "S3", "S4", "S5", "S6"]
    for e in doc["sensors"].values():
        assert e["optimised_pos_m"] < 0.01 and e["optimised_rot_deg"] < 0.5
        assert e["final_pos_m"] < 0.01 and e["final_rot_deg"] < 0.5
        assert e["chained_pos_m"] < 0.02
    rms = {m: sum(e[f"{m}_pos_m"] ** 2 for e in doc["sensors"].values()) ** 0.5
           for m in ("chained", "optimised")}
    assert rms["optimised"] <= rms["chained"]
    # ICP ran for every sensor and says what it did (kept only where it improves)
    assert sorted(r["sensor"] for r in doc["icp"]) == sorted(doc["sensors"])
    for r in doc["icp"]:
        assert "fitness" in r and "inlier_rmse_mm" in r and r["reason"], r
        if not r["accepted"]:
            s = doc["sensors"][r["sensor"]]
            assert s["final_pos_m"] == s["optimised_pos_m"]
    # the far pair (7.5 m from marker 1) gains most from the joint optimisation
    far = [doc["sensors"][s] for s in ("S5", "S6")]
    assert sum(e["optimised_pos_m"] for e in far) < sum(e["chained_pos_m"] for e in far)
    # marker 1 is 4.9 m from the middle pair: beyond depth range, rejected with the reason
    rej = {(o["sensor"], o["marker"]): o["reason"] for o in doc["rejected"]}
    assert "depth points" in rej[("S3", 1)]
    saved = load_calibration(out)
    assert saved.sensor_ids == sorted(doc["sensors"])


def test_calibrate_cli_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["calibrate", "--rig", str(tmp_path / "none.toml")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["calibrate", "--frames", "0"]) == 2
    assert "--frames" in capsys.readouterr().err
