"""The worked examples in ``examples/`` run and say what they claim."""

from __future__ import annotations

import csv
import importlib.util
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def _load(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, ROOT / "examples" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_vicon_trial_on_the_real_file(shared_data: Path, tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    trial = shared_data / "mocap" / "kineticstoolkit" / "walk.c3d"
    if not trial.is_file():
        pytest.skip(f"{trial} absent")
    ex = _load("vicon_trial")
    res = ex.analyse(trial, tmp_path)
    out = capsys.readouterr().out
    assert "LHEE" in out and "walking_speed_m_s" in out
    # every one of the file's 4 + 4 Nexus events found, each within 20 ms
    assert sorted(res["timing_ms"]) == ["foot_off", "foot_strike"]
    for kind, d in res["timing_ms"].items():
        assert len(d) == 4 and max(abs(x) for x in d) < 20.0, (kind, d)
    with (tmp_path / "steps.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(res["steps"]) >= 3
    assert all(0.3 < float(r["length_m"]) < 0.8 for r in rows)
    assert rows[0].keys() == res["steps"][0].keys()


def test_vicon_trial_refuses_a_bad_file_with_a_message(tmp_path: Path) -> None:
    bad = tmp_path / "notes.txt"
    bad.write_text("not a trial")
    run = subprocess.run([sys.executable, str(ROOT / "examples" / "vicon_trial.py"), str(bad),
                          "--out", str(tmp_path / "out")], capture_output=True, text=True,
                         timeout=120, cwd=ROOT)
    assert run.returncode == 2
    assert "unsupported file type '.txt'" in run.stderr and "Traceback" not in run.stderr


def test_compare_with_reference_demo_agrees_and_writes_pairs(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ex = _load("compare_with_reference")
    pairs = ex.demo_files(tmp_path)
    res = ex.compare(pairs, csv_path=tmp_path / "pairs.csv")
    for side in ("L", "R"):
        length = res["length_m"][side]
        assert length.n >= 15 and abs(length.bias) < 0.01 and length.icc_a1 > 0.9
        assert abs(res["duration_s"][side].bias) < 0.005
    with (tmp_path / "pairs.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == sum(a.n for a in res["length_m"].values())
    assert "ICC(A,1)" in capsys.readouterr().out


def test_compare_with_reference_names_a_time_offset(tmp_path: Path) -> None:
    ex = _load("compare_with_reference")
    pairs = ex.demo_files(tmp_path, n=1)
    from engine.errors import InputError

    with pytest.raises(InputError, match="not on one time axis; give --offset"):
        ex.compare(pairs, offset_s=3.0)
    # the right offset undoes a shifted reference
    assert ex.compare(pairs, offset_s=0.0)["length_m"]["L"].n >= 4


def test_compare_with_reference_says_when_a_side_has_too_few_pairs(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A short trial pairs fewer than the three steps per side agreement needs: each such
    row says so (the table was printed empty)."""
    from engine import write_trc
    from engine.sim import synth_walk, walk_markers

    ex = _load("compare_with_reference")
    f = tmp_path / "short.trc"
    write_trc(f, walk_markers(synth_walk(n_steps=5)))
    res = ex.compare([(f, f)])
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if "too few paired steps (3 needed)" in line]
    assert len(rows) == 6
    assert not any(res[p] for p in ("length_m", "width_m", "duration_s"))
    # the pair counts per side are those the statistics would have used
    n = {line.split()[2]: int(line.split()[3]) for line in rows if line.startswith("step time")}
    assert 0 < n["L"] < 3 and 0 < n["R"] < 3


def test_example_help_gives_the_whole_first_sentence() -> None:
    for name in ("vicon_trial", "compare_with_reference"):
        run = subprocess.run([sys.executable, str(ROOT / "examples" / f"{name}.py"), "--help"],
                             capture_output=True, text=True, timeout=120, cwd=ROOT)
        text = " ".join(run.stdout.split())
        first = " ".join(_load(name).__doc__.split("\n\n")[0].split())
        assert run.returncode == 0 and first.endswith(".") and first in text, text


def test_batch_gait_keeps_going_past_bad_files(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    from engine.io.trc import write_trc
    from engine.sim.straight_walk import synth_walk, walk_markers

    data = tmp_path / "lab"
    (data / "P01").mkdir(parents=True)
    write_trc(data / "P01" / "walk1.trc", walk_markers(synth_walk(step_length=0.62)))
    write_trc(data / "P01" / "walk2.trc", walk_markers(synth_walk(step_length=0.74)))
    (data / "P01" / "notes.csv").write_text("a,b\n1,2\n")  # not a skeleton CSV
    write_trc(data / "short.trc", walk_markers(synth_walk(n_steps=2)))  # too little walking
    ex = _load("batch_gait")
    out, steps = tmp_path / "summary.csv", tmp_path / "steps.csv"
    assert ex.main([str(data), "--out", str(out), "--steps", str(steps)]) == 0
    with out.open() as f:
        rows = {r["file"]: r for r in csv.DictReader(f)}
    assert sorted(rows) == ["P01/notes.csv", "P01/walk1.trc", "P01/walk2.trc", "short.trc"]
    assert float(rows["P01/walk1.trc"]["step_length_m"]) == pytest.approx(0.62, abs=0.01)
    assert float(rows["P01/walk2.trc"]["step_length_m"]) == pytest.approx(0.74, abs=0.01)
    assert rows["P01/walk1.trc"]["error"] == ""
    assert "first column must be 'time'" in rows["P01/notes.csv"]["error"]
    assert "step" in rows["short.trc"]["error"]
    with steps.open() as f:
        srows = list(csv.DictReader(f))
    assert {r["file"] for r in srows} == {"P01/walk1.trc", "P01/walk2.trc"}
    assert len(srows) == sum(int(rows[k]["n_steps"]) for k in ("P01/walk1.trc",
                                                                "P01/walk2.trc"))
    assert "2 of 4 files analysed" in capsys.readouterr().out
    empty = tmp_path / "empty"
    empty.mkdir()
    assert ex.main([str(empty), "--out", str(tmp_path / "none.csv")]) == 2
    assert "no .c3d, .trc or .csv file" in capsys.readouterr().err


def test_calibrate_simulated_finds_every_tripod_within_a_centimetre(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from engine.calibration import load_calibration

    ex = _load("calibrate_simulated")
    # one calibration (rendering dominates): the function the command line runs
    errors = ex.calibrate_avenue(frames=2, seed=1, out=tmp_path / "cal.json")
    out = capsys.readouterr().out
    for sid in ("S1", "S2", "S3", "S4", "S5", "S6"):
        assert f"\n{sid} " in out, out
    assert "calibration saved to" in out
    saved = load_calibration(tmp_path / "cal.json")
    assert saved.sensor_ids == ["S1", "S2", "S3", "S4", "S5", "S6"]
    assert sorted(errors) == saved.sensor_ids
    for sid, e in errors.items():
        assert e["final_pos_m"] < 0.01 and e["final_rot_deg"] < 0.3, (sid, e)


def test_fuse_skeletons_recovers_the_walk_and_names_too_short_a_walk(
        capsys: pytest.CaptureFixture[str]) -> None:
    ex = _load("fuse_skeletons")
    res = ex.fuse_walk(n_steps=14, seed=0)
    assert sorted(res) == ["mean", "one-sided", "weighted"]
    assert res["one-sided"]["sensors"] == ["S1", "S3", "S5"]
    assert len(res["weighted"]["sensors"]) == 6
    for name, row in res.items():
        assert row["step_length_m"] == pytest.approx(0.70, abs=0.02), (name, row)
        assert 0.05 < row["step_width_m"] < 0.15, (name, row)
        assert 0.5 < row["ankle_rms_cm"] < 5.0, (name, row)
    # gaitrig's estimator is closer to the truth than the paper's mean (far-leg bias)
    assert res["weighted"]["ankle_rms_cm"] < res["mean"]["ankle_rms_cm"]
    assert "ankle RMS" in capsys.readouterr().out
    assert ex.main(["--steps", "2"]) == 2
    assert "no straight walking found" in capsys.readouterr().err


def test_imu_orientation_demo_reads_its_file_back_and_scores_it(
        capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    ex = _load("imu_orientation")
    assert ex.main(["--demo"]) == 0
    out = capsys.readouterr().out
    assert "shank_l.csv: 2048 samples at 256.0 Hz" in out and "inclination" in out
    res = ex.estimate(ex.write_demo_csv(tmp_path / "shank.csv"), "ENU")
    assert sorted(res) == ["gaitrig causal", "gaitrig offline", "madgwick"]
    for name, e in res.items():
        assert 0.0 < e["inclination_deg"] < 4.0 and e["total_deg"] < 6.0, (name, e)
    no_ref = tmp_path / "plain.csv"
    rows = np.loadtxt(tmp_path / "shank.csv", delimiter=",", skiprows=1)[:, :10]
    np.savetxt(no_ref, rows, delimiter=",", comments="", fmt="%.9g",
               header="time_s,gyr_x_rads,gyr_y_rads,gyr_z_rads,acc_x_ms2,acc_y_ms2,"
                      "acc_z_ms2,mag_x_ut,mag_y_ut,mag_z_ut")
    assert ex.main([str(no_ref)]) == 2
    assert "has no reference orientation" in capsys.readouterr().err


def test_imu_orientation_on_a_real_broad_trial(shared_data: Path) -> None:
    trial = shared_data / "imu" / "broad" / "07_undisturbed_fast_rotation_B.hdf5"
    if not trial.is_file():
        pytest.skip(f"{trial} absent")
    res = _load("imu_orientation").estimate(trial)
    # BROAD's undisturbed trials: gaitrig's filter within 3° of the optical reference
    for name in ("gaitrig causal", "gaitrig offline"):
        assert res[name]["total_deg"] < 3.0, (name, res[name])


def test_examples_use_public_names_only() -> None:
    """An example teaches the API: it imports from ``engine`` or a subpackage's
    ``__all__``, never a private module path that a refactor may move."""
    import ast
    import importlib

    problems = []
    for path in sorted((ROOT / "examples").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("engine"):
                public = getattr(importlib.import_module(node.module or ""), "__all__", [])
                for alias in node.names:
                    if alias.name not in public:
                        problems.append(f"{path.name}: from {node.module} import {alias.name}")
    assert not problems, "\n".join(problems)
