"""``gaitrig gait`` end to end (in-process through app.cli.main and as a subprocess)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from engine.io.c3d import write_c3d
from engine.io.markers import MarkerTrajectories
from engine.io.trc import write_trc
from engine.sim.straight_walk import synth_walk, walk_markers

ROOT = Path(__file__).resolve().parents[2]


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    rc = main(["gait", *argv])
    out, err = capsys.readouterr()
    return rc, out, err


def test_json_output_on_synthetic_trc(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    p = tmp_path / "walk.trc"
    write_trc(p, walk_markers(synth_walk(step_length=0.66, step_width=0.13), up="y"), units="mm")
    rc, out, err = _run([str(p), "--json"], capsys)
    assert rc == 0 and err == ""
    doc = json.loads(out)
    assert set(doc) == {"events", "steps", "strides", "summary"}
    assert all(e["kind"] == "placement" and e["side"] in "LR" for e in doc["events"])
    assert np.median([s["length_m"] for s in doc["steps"]]) == pytest.approx(0.66, abs=0.005)
    assert np.median([s["width_m"] for s in doc["steps"]]) == pytest.approx(0.13, abs=0.005)
    assert doc["summary"]["walking_speed_m_s"] == pytest.approx(0.66 / 0.55, rel=0.01)


def test_table_output_and_overrides(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    names = {"ankleL": "sub:LeftFoot_Marker", "ankleR": "sub:RightFoot_Marker"}
    m = walk_markers(synth_walk(), labels=names)
    m.times = np.round(m.times * 100) / 100
    p = tmp_path / "odd.c3d"
    write_c3d(p, m, units="m")
    rc, out, err = _run([str(p), "--left", "LeftFoot_Marker", "--right", "sub:RightFoot_Marker",
                         "--up", "z", "--units", "m", "--method", "heelstrike"], capsys)
    assert rc == 0, err
    assert "walking speed: 1.27 m/s" in out and "step length cm" in out and "stance %" in out


@pytest.mark.parametrize("case", ["missing", "no_feet", "too_short", "garbage"])
def test_errors_are_one_line_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                    case: str) -> None:
    w = synth_walk()
    if case == "missing":
        p = tmp_path / "nope.c3d"
        expect = "not found"
    elif case == "no_feet":
        m = walk_markers(w)
        keep = [i for i, lab in enumerate(m.labels) if lab.endswith(("ASI", "PSI"))]
        m2 = MarkerTrajectories(m.times, m.positions[:, keep], [m.labels[i] for i in keep],
                                m.rate, "m")
        p = tmp_path / "pelvis_only.trc"
        write_trc(p, m2)
        expect = "no usable left ankle or heel and no right ankle or heel"
    elif case == "too_short":
        p = tmp_path / "short.trc"
        write_trc(p, walk_markers(synth_walk(n_steps=2)))
        expect = "at least two steps"
    else:
        p = tmp_path / "garbage.c3d"
        p.write_bytes(b"\x00\x01garbage" * 10)
        # (ezc3d's "File must be a valid c3d file: iostream error" was the end of it)
        expect = ("gaitrig gait: error: cannot read garbage.c3d as C3D: the file is damaged "
                  "or not a C3D file (export it again from the motion-capture software, "
                  "as C3D)\n")
    rc, out, err = _run([str(p), "--json"], capsys)
    assert rc == 2 and out == ""
    assert err.count("\n") == 1 and expect in err and "Traceback" not in err
    if case == "garbage":
        assert err == expect and "iostream" not in err


def test_report_of_a_damaged_c3d_says_to_export_it_again(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``gaitrig report`` shows the same message as ``gaitrig gait``, naming the file."""
    p = tmp_path / "trial 3.c3d"
    p.write_bytes(b"not a c3d file at all")
    rc = main(["report", str(p), "--subject", "P1", "-o", str(tmp_path / "r.html")])
    out, err = capsys.readouterr()
    assert rc == 2 and out == ""
    assert err == ("gaitrig report: error: trial 3.c3d: cannot read trial 3.c3d as C3D: the "
                   "file is damaged or not a C3D file (export it again from the "
                   "motion-capture software, as C3D)\n")


def test_gait_and_report_of_a_c3d_file_cut_short_say_so(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A C3D file whose copy stopped half-way was analysed as half the walk (its first
    kilobyte as 525 frames of gaps); ``gaitrig gait`` and ``gaitrig report`` refuse it
    in one line that says it is cut short and to copy or export it again."""
    whole = tmp_path / "whole.c3d"
    write_c3d(whole, walk_markers(synth_walk()), units="mm")
    p = tmp_path / "walk.c3d"
    p.write_bytes(whole.read_bytes()[:len(whole.read_bytes()) // 2])
    why = ("cannot read walk.c3d as C3D: the file is cut short (it holds 259 of the 525 "
           "frames its header announces); copy or export it again\n")
    rc, out, err = _run([str(p), "--json"], capsys)
    assert (rc, out, err) == (2, "", f"gaitrig gait: error: {why}")
    rc = main(["report", str(p), "--subject", "P1", "-o", str(tmp_path / "r.html")])
    out, err = capsys.readouterr()
    assert (rc, out, err) == (2, "", f"gaitrig report: error: walk.c3d: {why}")


def test_subprocess_on_vicon_file(shared_data: Path) -> None:
    f = shared_data / "mocap" / "kineticstoolkit" / "walk.c3d"
    r = subprocess.run([sys.executable, "-m", "app.cli", "gait", str(f), "--method",
                        "heelstrike", "--json"], capture_output=True, text=True, cwd=ROOT,
                       timeout=60, check=False)
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    strikes = [e for e in doc["events"] if e["kind"] == "foot_strike"]
    assert len(strikes) == 4
    assert doc["summary"]["n_steps"] == 3


def test_output_into_a_closed_pipe_is_quiet(tmp_path: Path) -> None:
    """``gaitrig gait FILE | head -1``: the reader leaves early; no traceback is shown."""
    p = tmp_path / "walk.trc"
    write_trc(p, walk_markers(synth_walk(step_length=0.66, step_width=0.13), up="y"), units="mm")
    proc = subprocess.Popen([sys.executable, "-m", "app.cli", "gait", str(p)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # the reader is gone before the first write (as `head` after its lines)
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=60) in (0, 1)
    assert "Traceback" not in err and "BrokenPipe" not in err, err


@pytest.mark.parametrize("argv", [["--up", "-y"], ["--up=-y"], ["--up", "-y", "--json"]])
def test_a_negative_axis_is_read_as_the_value_of_up(argv: list[str]) -> None:
    """``--up -y`` (argparse would take "-y" for an option) means the same as ``--up=-y``."""
    from app.cli import build_parser

    args = build_parser().parse_args(["gait", "walk.trc", *argv])
    assert args.up == "-y" and args.file == "walk.trc"


@pytest.mark.parametrize(("argv", "up", "units"), [
    (["--up", "Y", "--units", "MM"], "y", "mm"), (["--up=-Z"], "-z", None),
    (["--up", "+x", "--units", "Cm"], "x", "cm"),
])
def test_axis_and_unit_in_any_case(argv: list[str], up: str, units: str | None) -> None:
    """``--up Y``/``+x``/``--units MM``, as file headers and other tools spell them."""
    from app.cli import build_parser

    args = build_parser().parse_args(["gait", "walk.trc", *argv])
    assert (args.up, args.units) == (up, units)


@pytest.mark.parametrize(("argv", "said"), [
    (["-y"], "write --up -y"),                 # an axis without --up
    (["--up", "y", "-x"], "write --up -x"),    # a second axis after a complete --up
    (["--up", "w"], "invalid choice: 'w'"),
])
def test_an_axis_in_the_wrong_place_is_refused(argv: list[str], said: str,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        main(["gait", "walk.trc", *argv])
    assert e.value.code == 2
    assert said in capsys.readouterr().err


def test_up_without_an_axis_says_which(tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    p = tmp_path / "walk.trc"
    write_trc(p, walk_markers(synth_walk(), up="y"), units="mm")
    rc, out, err = _run([str(p), "--up"], capsys)
    assert rc == 2 and out == ""
    assert "--up needs an axis" in err and "-y" in err


def test_step_table_names_its_time_columns(tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    """The step table's two times are the instant a step ends and its duration (both were
    headed 'time s')."""
    p = tmp_path / "walk.trc"
    write_trc(p, walk_markers(synth_walk(step_time=0.55)), units="mm")
    rc, out, err = _run([str(p)], capsys)
    assert rc == 0, err
    lines = out.splitlines()
    head = next(i for i, line in enumerate(lines) if line.split()[:2] == ["step", "side"])
    assert lines[head].split() == ["step", "side", "at", "s", "length", "cm", "width", "cm",
                                   "duration", "s"]
    first = lines[head + 1].split()
    assert float(first[-1]) == pytest.approx(0.55, abs=0.01)
    assert float(first[2]) > 0.55  # the instant, on the file's time axis


def test_max_crossing_gap_reproduces_the_papers_rule(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A skeleton CSV whose left ankle is lost for 0.3 s at each crossing (seen from the
    right only): found by default, and ``--max-crossing-gap 0`` (the seed paper's rule,
    crossings between consecutive samples only) finds too few steps."""
    from engine.gait import GaitAnalysis
    from engine.io.csv import write_skeleton_csv
    from engine.mocap import feet_from_skeleton
    from engine.sim.straight_walk import walk_skeleton
    from engine.skeleton import KINECT_V2, SkeletonSeries, TrackingState

    w = synth_walk(n_steps=12, rate=30.0)
    P = walk_skeleton(w)
    states = np.full(P.shape[:2], TrackingState.TRACKED, np.uint8)
    full = GaitAnalysis().fit(feet_from_skeleton(SkeletonSeries(w.times, P, states, KINECT_V2)))
    ankle = KINECT_V2.joints.index("AnkleLeft")
    for e in full.events_:
        hidden = np.abs(w.times - e.time_s) <= 0.15
        P[hidden, ankle] = np.nan
        states[hidden, ankle] = TrackingState.NOT_TRACKED
    p = tmp_path / "one side.csv"
    write_skeleton_csv(p, SkeletonSeries(w.times, P, states, KINECT_V2))
    rc, out, err = _run([str(p), "--json"], capsys)
    assert rc == 0, err
    assert len(json.loads(out)["steps"]) == len(full.steps_)
    rc, out, err = _run([str(p), "--json", "--max-crossing-gap", "0"], capsys)
    assert rc == 2 and "step" in err, (rc, out, err)
    rc, out, err = _run([str(p), "--max-crossing-gap", "2"], capsys)
    assert rc == 2 and err == ("gaitrig gait: error: --max-crossing-gap must be between 0 "
                               "and 1 s (a longer gap can hide a whole step), got 2\n"), err
