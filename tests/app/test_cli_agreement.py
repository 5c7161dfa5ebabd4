"""``gaitrig agreement``: a validation study from pairs of files (measured, reference).

Three simulated subjects walk twice; each walk is written as a gaitrig skeleton CSV
(joint centres, 30 Hz) and as a reference TRC or C3D (Plug-in Gait markers, 100 Hz) of
the same walk with steps 2 cm wider (each ankle 1 cm further out): every step width's
bias (measured - reference) is -2 cm, every other parameter's 0.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from engine.io.c3d import write_c3d
from engine.io.csv import write_skeleton_csv
from engine.io.trc import write_trc
from engine.sim.straight_walk import synth_walk, walk_markers, walk_skeleton
from engine.skeleton import KINECT_V2, SkeletonSeries

#: how much the reference of the shifted walk started before the measured file, s
SHIFT_S = 1.5


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Folder with s{i}w{j}.csv (measured) and s{i}w{j}.trc/.c3d (reference) files, and
    shifted.trc: s2w1's reference on a time axis starting SHIFT_S s before it."""
    d = tmp_path_factory.mktemp("study")
    for i in range(3):
        for j in range(2):
            kw = {"step_length": 0.60 + 0.06 * i + 0.01 * j, "step_time": 0.50 + 0.03 * i,
                  "n_steps": 10}
            w = synth_walk(step_width=0.10 + 0.02 * i, rate=30.0, **kw)  # type: ignore[arg-type]
            P = walk_skeleton(w)
            write_skeleton_csv(d / f"s{i}w{j}.csv", SkeletonSeries(
                w.times, P, np.full(P.shape[:2], 2, np.uint8), KINECT_V2))
            ref = walk_markers(synth_walk(step_width=0.12 + 0.02 * i, rate=100.0,
                                          **kw))  # type: ignore[arg-type]
            (write_c3d if j else write_trc)(d / f"s{i}w{j}.{'c3d' if j else 'trc'}", ref)
            if (i, j) == (2, 1):
                ref.times = ref.times + SHIFT_S
                write_trc(d / "shifted.trc", ref)
    (d / "bad.trc").write_text("not a TRC file\n")
    return d


def _ref(i: int, j: int) -> str:
    return f"s{i}w{j}.{'c3d' if j else 'trc'}"


def _pairs(d: Path) -> list[str]:
    return [a for i in range(3) for j in range(2)
            for a in ("--pair", f"P{i}", str(d / f"s{i}w{j}.csv"), str(d / _ref(i, j)))]


def _json(argv: list[str], capsys: pytest.CaptureFixture[str]) -> dict:  # type: ignore[type-arg]
    assert main(["agreement", *argv, "--json"]) == 0
    doc: dict = json.loads(capsys.readouterr().out)  # type: ignore[type-arg]
    return doc


def _rows(doc: dict) -> dict[str, dict]:  # type: ignore[type-arg]
    return {r["label"]: r for r in doc["rows"]}


def test_json_rows_have_the_papers_labels_and_the_known_bias(
        study: Path, capsys: pytest.CaptureFixture[str]) -> None:
    doc = _json(_pairs(study), capsys)
    assert (doc["subjects"], doc["trials"], doc["unmatched"], doc["failed"]) == (3, 6, [], [])
    rows = _rows(doc)
    assert next(iter(rows)) == "AV walking speed (cm/s)"
    assert rows["AV walking speed (cm/s)"]["n"] == 3
    for side in ("L", "R"):
        for label in (f"Step width {side} (cm)", f"AV step width {side} (cm)"):
            assert rows[label]["bias"] == pytest.approx(-2.0, abs=0.05), label
            assert rows[label]["mean_reference"] - rows[label]["mean_measured"] == \
                pytest.approx(2.0, abs=0.05)
        for label in (f"Step length {side} (cm)", f"Step time {side} (s)",
                      f"Stride length {side} (cm)"):
            assert rows[label]["bias"] == pytest.approx(0.0, abs=0.05), label
        # 10 strikes a walk: 4 or 5 steps of a side matched in each of 6 trials
        assert 20 <= rows[f"Step length {side} (cm)"]["n"] <= 30
        assert rows[f"AV step length {side} (cm)"]["n"] == 3
    assert rows["AV step width AVG (cm)"]["unit"] == "cm" and rows["AV step width AVG (cm)"][
        "table"] == 2
    assert rows["Step length L (cm)"]["icc_a1"] > 0.99


def test_csv_and_text_output(study: Path, tmp_path: Path,
                             capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "study.csv"
    assert main(["agreement", *_pairs(study), "-o", str(out)]) == 0
    said = capsys.readouterr().out
    assert said.startswith(f"gaitrig agreement: {out} (3 subjects, 6 trials, ")
    lines = out.read_text().splitlines()
    assert lines[0].startswith("table,parameter,level,unit,n,mean_measured,")
    width = [ln.split(",") for ln in lines if ",step width,L," in ln]
    assert len(width) == 1 and float(width[0][11]) == pytest.approx(-2.0, abs=0.05)

    assert main(["agreement", *_pairs(study), "--system", "Kinects",
                 "--reference-name", "Vicon"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("Kinects vs Vicon: 3 subjects, 6 trials (crossing method")
    head = next(ln for ln in text.splitlines() if ln.startswith("parameter"))
    assert head.split() == ["parameter", "Kinects", "Vicon", "r", "p", "N", "bias", "RPC",
                            "CV", "%", "ICC(A,1)"]
    row = next(ln for ln in text.splitlines() if ln.startswith("AV step width R (cm)"))
    # measured mean ± SD, reference mean ± SD, r, p, N, bias, RPC
    assert row.split()[5:16] == ["12.0", "±", "2.0", "14.0", "±", "2.0", "1.00", "<0.001",
                                 "3", "-2.0", "0.0"], row
    assert "Table 1" in text and "Table 2" in text and "note:" not in text


def test_a_failing_file_is_named_and_the_rest_computed(
        study: Path, capsys: pytest.CaptureFixture[str]) -> None:
    argv = _pairs(study)
    argv[argv.index(str(study / "s2w1.c3d"))] = str(study / "bad.trc")
    assert main(["agreement", *argv]) == 0
    text = capsys.readouterr().out
    assert "3 subjects, 5 trials" in text and "AV step width AVG (cm)" in text
    note = [ln for ln in text.splitlines() if ln.startswith("note:")]
    assert len(note) == 1 and "bad.trc was left out" in note[0] and "TRC" in note[0], note
    doc = _json(argv, capsys)
    assert doc["trials"] == 5 and [f["file"] for f in doc["failed"]] == [str(study / "bad.trc")]
    assert "TRC" in doc["failed"][0]["error"]


def test_manifest_with_relative_paths_and_an_offset(
        study: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The shifted reference is put on the measured file's axis by offset_s = -1.5 (added
    to the reference's times); without it its walk's steps match nothing."""
    lines = ["subject,measured,reference,offset_s"]
    lines += [f"P{i},s{i}w{j}.csv,{_ref(i, j)}," for i in range(3) for j in range(2)
              if (i, j) != (2, 1)]
    (study / "manifest.csv").write_text("\n".join([*lines, f"P2,s2w1.csv,shifted.trc,"
                                                               f"{-SHIFT_S}"]) + "\n")
    doc = _json(["--manifest", str(study / "manifest.csv")], capsys)
    assert (doc["trials"], doc["unmatched"], doc["failed"]) == (6, [], [])
    assert _rows(doc)["Step width R (cm)"]["bias"] == pytest.approx(-2.0, abs=0.05)
    assert _rows(doc)["Step width R (cm)"]["n"] == _rows(
        _json(_pairs(study), capsys))["Step width R (cm)"]["n"]
    # the same walk with a wrong offset (0.2 s: less than a step's 0.56 s) matches nothing
    (study / "wrong.csv").write_text("\n".join([*lines, "P2,s2w1.csv,shifted.trc,0.2"]))
    doc = _json(["--manifest", str(study / "wrong.csv")], capsys)
    assert doc["unmatched"] == ["P2: s2w1.csv vs shifted.trc"] and doc["trials"] == 6


def test_bad_input_is_exit_code_2_with_a_clear_message(
        study: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "cols.csv").write_text("subject,file\nP1,a.csv\n")
    (tmp_path / "line.csv").write_text(f"subject,measured,reference\nP1,{study}/s0w0.csv,"
                                       f"{study}/s0w0.trc\nP2,{study}/s1w0.csv,\n")
    (tmp_path / "off.csv").write_text(f"subject,measured,reference,offset_s\n"
                                      f"P1,{study}/s0w0.csv,{study}/s0w0.trc,soon\n")
    (tmp_path / "empty.csv").write_text("subject,measured,reference\n")
    good = ["--pair", "P1", str(study / "s0w0.csv"), str(study / "s0w0.trc")]
    cases = [
        (["--pair", "P1", str(study / "s0w0.csv"), str(tmp_path / "nope.c3d")],
         f"no such file: {tmp_path / 'nope.c3d'}"),
        (["--manifest", str(tmp_path / "none.csv")], "cannot read the manifest"),
        (["--manifest", str(tmp_path / "cols.csv")], "has no measured, reference column"),
        (["--manifest", str(tmp_path / "line.csv")], "line.csv line 3: no reference given"),
        (["--manifest", str(tmp_path / "off.csv")], "line 2: offset_s 'soon' is not a number"),
        (["--manifest", str(tmp_path / "empty.csv")], "lists no walk"),
        ([*good, "-o", str(tmp_path / "x.txt")], ".csv, .html or .pdf"),
        ([*good, "--max-dt", "0"], "--max-dt must be more than 0"),
    ]
    for argv, words in cases:
        assert main(["agreement", *argv]) == 2, argv
        out, err = capsys.readouterr()
        assert err.startswith("gaitrig agreement: error:") and err.count("\n") == 1, err
        assert words in err, (words, err)
        assert out == ""
    with pytest.raises(SystemExit) as e:  # neither --pair nor --manifest: argparse's
        main(["agreement"])
    assert e.value.code == 2 and "--pair" in capsys.readouterr().err


def test_no_row_is_exit_code_1_naming_why(study: Path, capsys: pytest.CaptureFixture[str]
                                          ) -> None:
    assert main(["agreement", "--pair", "P1", str(study / "s0w0.csv"),
                 str(study / "bad.trc")]) == 1
    out, err = capsys.readouterr()
    assert out == "" and "bad.trc was left out" in err and "no agreement can be computed" in err


def test_a_measured_files_advice_is_not_the_reference_options(
        tmp_path: Path, study: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The file options are the reference's: an error of a measured file that a file
    option would fix is said without that option's advice, pointing to gaitrig gait."""
    # foot markers of names no lab uses: gaitrig gait would say "with --left/--right"
    m = walk_markers(synth_walk(n_steps=10), labels={"ankleL": "M1", "ankleR": "M2"})
    write_trc(tmp_path / "mm.trc", m)
    argv = ["--pair", "P1", str(tmp_path / "mm.trc"), str(study / "s0w0.trc"), "--json"]
    assert main(["agreement", *argv]) == 1
    doc = json.loads(capsys.readouterr().out)
    [failed] = doc["failed"]
    assert "available labels: M1, M2" in failed["error"], failed
    assert "--left" not in failed["error"] and "gaitrig gait mm.trc" in failed["error"]


def test_a_real_reference_against_itself(shared_data: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    """The kineticstoolkit walk (3 steps: 2 left, 1 right) as the same walk of three
    subjects: every bias is 0, the statistics of values without spread (r of three equal
    subject averages) are JSON nulls, not NaN."""
    f = shared_data / "mocap" / "kineticstoolkit" / "walk.c3d"
    if not f.is_file():
        pytest.skip(f"{f} is absent")
    argv = [a for k in range(3) for a in ("--pair", f"S{k}", str(f), str(f))]
    assert main(["agreement", *argv, "--json"]) == 0
    text = capsys.readouterr().out
    assert "NaN" not in text
    doc = json.loads(text)
    rows = _rows(doc)
    assert doc["subjects"] == 3 and rows["AV walking speed (cm/s)"]["n"] == 3
    assert all(r["bias"] == pytest.approx(0.0, abs=1e-9) for r in doc["rows"])
    assert rows["Step width L (cm)"]["n"] == 6 and rows["AV step width R (cm)"]["r"] is None


def test_html_and_pdf_reports(study: Path, tmp_path: Path,
                              capsys: pytest.CaptureFixture[str]) -> None:
    """-o .html/.pdf: engine.report.study's report, with the system names as headings,
    what was compared, and the trial left out named."""
    argv = _pairs(study)
    argv[argv.index(str(study / "s2w1.c3d"))] = str(study / "bad.trc")
    out = tmp_path / "study.html"
    assert main(["agreement", *argv, "-o", str(out), "--system", "Kinects",
                 "--reference-name", "Vicon", "--title", "Kinects vs Vicon, 2025"]) == 0
    assert capsys.readouterr().out.startswith(f"gaitrig agreement: {out} (3 subjects, 5 trials")
    html = out.read_text()
    assert "Kinects vs Vicon, 2025" in html and ">Vicon<" in html and ">Kinects<" in html
    assert "Subjects: P0 (2 trials), P1 (2 trials), P2 (2 trials) given." in html
    assert "bad.trc was left out" in html and "AV step width AVG (cm)" in html
    pdf = tmp_path / "study.pdf"
    assert main(["agreement", *argv, "-o", str(pdf)]) == 0
    assert pdf.read_bytes().startswith(b"%PDF")
