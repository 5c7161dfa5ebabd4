"""The report data the server builds from analyses: units and facts a clinician reads."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from app.server import analysis as an
from engine.report.render import ReportData, TrialData, render_html


def _steps(n: int, dt_err_s: float, rng: np.random.Generator) -> tuple[list[dict], list[dict]]:
    meas, ref = [], []
    t = 0.0
    for i in range(n):
        side = "L" if i % 2 == 0 else "R"
        dur = 0.55 + 0.02 * rng.standard_normal()
        t += dur
        ref.append({"side": side, "time_s": t, "length_m": 0.65, "width_m": 0.1,
                    "duration_s": dur})
        meas.append({"side": side, "time_s": t + 0.01,
                     "length_m": 0.65 + 0.01 * rng.standard_normal(),
                     "width_m": 0.1 + 0.01 * rng.standard_normal(),
                     "duration_s": dur + dt_err_s + 0.002 * rng.standard_normal()})
    return meas, ref


def test_step_time_agreement_is_in_ms_so_a_few_ms_of_bias_shows() -> None:
    """A 4 ms step-time bias used to read '0.00' (and '-0.00') in seconds."""
    meas, ref = _steps(20, 0.004, np.random.default_rng(0))
    rows, figs = an.agreement_rows(meas, ref)
    st = [r for r in rows if r.parameter == "Step time"]
    assert st and all(r.unit == "ms" for r in st)
    both = next(r for r in st if r.level.endswith("L+R"))
    assert 3.0 < both.bias < 5.0
    assert any("step time" in c for c, _ in figs)
    html = render_html(ReportData("P-1", [TrialData("walk", {"steps": meas})], agreement=rows))
    cells = html[html.index("Agreement with the reference system"):]
    assert f"<td>{both.bias:.2f}</td>" in cells and f"{both.bias:.2f}" != "0.00"


def _analysis(rec_id: str, offsets: dict[str, float], version: str,
              residual: float) -> dict:
    steps = [{"side": "LR"[i % 2], "time_s": 0.55 * i, "length_m": 0.65, "width_m": 0.1,
              "duration_s": 0.55} for i in range(12)]
    return {"rec_id": rec_id, "ok": True, "sensors_used": list(offsets),
            "gait": {"events": [], "steps": steps, "strides": [], "summary": {}},
            "sensors": {k: {"clock_offset_ms": v, "clock_uncertainty_ms": 0.1,
                            "calibration_residual_mm": residual,
                            "calibration_version": version, "mirrored_pct": 0.0}
                        for k, v in offsets.items()},
            "fusion": {"tracked_pct": {"AnkleLeft": 90.0}, "gaps_filled": 2}}


def test_quality_of_several_recordings_shows_every_recordings_offsets() -> None:
    """Three recordings synchronised 135.60, 136.08 and 136.71 ms apart (a real subject
    report): the table used to print the last recording's 135.60 alone, unlabelled, and
    only the last calibration version and residual."""
    analyses = [_analysis("R1", {"S1": 136.71, "S2": -459.57}, "3", 2.0),
                _analysis("R2", {"S1": 136.08, "S2": -460.83}, "3", 4.5),
                _analysis("R3", {"S1": 135.60, "S2": -461.83}, "4", 1.0)]
    html = render_html(an.build_report("P-1", analyses))
    quality = html[html.index("Data quality"):]
    assert "135.60 to 136.71" in quality and "-461.83 to -459.57" in quality
    assert "lowest to highest" in quality and "Over the 3 recordings" in quality
    assert "3, 4" in quality  # both calibration versions
    assert "<td>4.5</td>" in quality  # the largest residual, not the last (1.0)
    one = render_html(an.build_report("P-1", analyses[:1]))
    assert "136.71" in one and "lowest to highest" not in one


def test_mirrored_sensors_of_one_recording_make_one_note() -> None:
    """Six sensors behind the subject in one recording used to give six near-identical
    notes, burying the others (a real report had eight such lines)."""
    a = _analysis("R9", {f"S{k}": 0.0 for k in range(1, 7)}, "3", 1.0)
    for k, f in enumerate(a["sensors"].values()):
        f["mirrored_pct"] = 100.0 if k else 20.0
    q = an.quality_from_analyses([a])
    mirrored = [n for n in q.notes if "from behind" in n]
    assert len(mirrored) == 1, q.notes
    assert "Recording R9" in mirrored[0]
    assert "S1 (20 %)" in mirrored[0] and "S6 (100 %)" in mirrored[0]


def test_trials_line_gives_steps_per_trial_and_sensors_once() -> None:
    """The trials line repeated '(S1, S2)' after every recording and gave only the total
    of steps, so a 3-step trial among 12-step ones could not be seen."""
    analyses = [_analysis(f"R{k}", {"S1": 1.0, "S2": 2.0}, "3", 1.0) for k in (1, 2, 3)]
    analyses[2]["gait"]["steps"] = analyses[2]["gait"]["steps"][:3]
    html = render_html(an.build_report("P-1", analyses))
    line = re.search(r"Trials used</th><td[^>]*>(.*?)</td>", html, re.S)
    assert line is not None
    assert line.group(1) == "3, 27 steps: R1 (12 steps); R2 (12 steps); R3 (3 steps)"
    analyses[2]["sensors_used"] = ["S1"]
    html = render_html(an.build_report("P-1", analyses))
    assert "R3 (S1) (3 steps)" in html  # trials that differ in sensors say so


def test_agreement_says_what_it_rests_on_and_flags_few_pairs() -> None:
    """A subject report of three trials with a reference on one said neither which trial
    nor how many pairs; rows of 3 pairs showed r, p and ICC without a caution."""
    rng = np.random.default_rng(3)
    analyses = [_analysis(f"R{k}", {"S1": 1.0}, "3", 1.0) for k in (1, 2, 3)]
    meas, ref = _steps(6, 0.004, rng)
    analyses[1]["gait"]["steps"] = meas
    html = render_html(an.build_report("P-1", analyses, references={"R2": ref}))
    section = html[html.index("Agreement with the reference system"):]
    assert "Steps of trial R2 (1 of 3 trials)" in section and ": 6 pairs" in section
    # named by the clinician's trial label, as the Per trial table names it
    labelled = render_html(an.build_report("P-1", analyses, references={"R2": ref},
                                           trial_labels={"R2": "walk 2", "R1": "walk 1"}))
    section = labelled[labelled.index("Agreement with the reference system"):]
    assert "Steps of trial walk 2 (1 of 3 trials)" in section, section[:600]
    assert "<td>3&nbsp;†</td>" in section and "Fewer than 10 pairs" in section
    assert "<td>6&nbsp;†</td>" in section


def test_tracked_share_says_it_counts_every_frame_of_the_recording() -> None:
    """47 % tracked in a recording where the walker was out of view half the time read
    'Only 47 % of joint samples were tracked; check sensor placement and occlusions',
    sending the clinician after a fault that was not there."""
    a = _analysis("R1", {"S1": 1.0}, "3", 1.0)
    a["fusion"]["tracked_pct"] = {"AnkleLeft": 47.0, "AnkleRight": 47.0}
    html = render_html(an.build_report("P-1", [a]))
    assert "47.0 % of the recording's frames" in html
    assert "the subject was out of the sensors" in html
    assert "check sensor placement and occlusions" not in html


def test_subject_header_gives_the_age_at_the_sessions() -> None:
    """Only 'Born 1958' was shown: the reader had to work out the age that decides which
    normative band applies (one source studied adults over 70)."""
    import datetime as dt
    from types import SimpleNamespace

    from app.api.routes.reports import _subject_info

    subj = SimpleNamespace(height_m=1.74, leg_length_m=None, sex="female", birth_year=1958)
    one = _subject_info(subj, [dt.date(2026, 11, 20)])
    assert one["Born"] == "1958" and one["Age"] == "≈ 68 y at the session"
    two = _subject_info(subj, [dt.date(2025, 3, 1), dt.date(2026, 11, 20)])
    assert two["Age"] == "≈ 67–68 y at the sessions"
    assert "Age" not in _subject_info(SimpleNamespace(birth_year=None), [dt.date(2026, 1, 1)])


def test_interpolated_gaps_are_a_count_that_says_of_what() -> None:
    """'Short gaps interpolated  71' gave a bare number: frames? %? gaps of what?"""
    html = render_html(an.build_report("P-1", [_analysis("R1", {"S1": 1.0}, "3", 1.0)]))
    assert "2 gaps in single joints' trajectories" in html


def test_trials_are_named_by_their_labels_and_keep_their_recording_ids() -> None:
    """A clinician's trial labels name the trials ("walk 3"), the recording id stays
    beside each in "Trials used"; a label given twice keeps the id in the name, and a
    trial without a label is named by its id."""
    assert an.trial_names({"R1": "walk 1", "R2": " ", "R3": "fast", "R4": "fast"}) == {
        "R1": "walk 1", "R2": "R2", "R3": "fast (R3)", "R4": "fast (R4)"}
    analyses = [_analysis(f"R{k}", {"S1": 1.0, "S2": 2.0}, "3", 1.0) for k in (1, 2, 3)]
    html = render_html(an.build_report("P-1", analyses, trial_labels={
        "R1": "walk 1", "R2": "walk 2"}))
    line = re.search(r"Trials used</th><td[^>]*>(.*?)</td>", html, re.S)
    assert line is not None
    assert line.group(1) == ("3, 36 steps: walk 1 — R1 (12 steps); walk 2 — R2 (12 steps); "
                             "R3 (12 steps)")
    assert re.search(r"<th scope=\"row\"[^>]*>walk 2</th>", html)  # the "Per trial" row


def test_a_note_names_an_unused_recording_by_its_trial_label(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """"Recording R20261124-… was not used" named the recording by an id the clinician
    never sees on the Record page: a note names the trial's label, the id beside it (a
    trial without a label keeps the id alone), for a failed analysis, a recording not
    complete on the server and a reference that could not be used."""
    assert an.recording_named("R9", "walk  3") == "Trial “walk 3” (recording R9)"
    assert an.recording_named("R9", " ") == "Recording R9"
    assert an.recording_named("R9", "walk 3", "on_nodes") == (
        "Trial “walk 3” (recording R9, still on the sensors)")
    assert an.recording_named("R9", "", "transferring") == (
        "Recording R9 (being copied to the server)")
    analyses = [_analysis("R1", {"S1": 1.0}, "3", 1.0),
                {"rec_id": "R2", "ok": False, "error": "no steps were found"},
                {"rec_id": "R3", "ok": False, "error": "no steps were found"}]
    analyses[0]["sensors"]["S1"]["mirrored_pct"] = 12.0  # its other notes too
    data = an.build_report("P-1", analyses, trial_labels={"R1": "walk 1", "R2": "walk 2"})
    assert any(n.startswith("Trial “walk 1” (recording R1): left/right labels were corrected")
               for n in data.quality.notes), data.quality.notes
    assert data.quality.notes[-2:] == [
        "Trial “walk 2” (recording R2) was not used: no steps were found",
        "Recording R3 was not used: no steps were found"]
    assert "Trial “walk 2” (recording R2) was not used" in render_html(data)

    # a subject's report: one recording analysed, one still on the sensors, one with a
    # reference file that cannot be read
    from app.api.routes import reports as rr

    monkeypatch.setattr(an, "part_dirs", lambda d: {"S1": d})
    monkeypatch.setattr(an, "analyse_recording",
                        lambda d, options, live: _analysis(d.name, {"S1": 1.0}, "3", 1.0))
    bad = tmp_path / "ref.csv"
    bad.write_text("not a reference\n")
    src = rr.SubjectReportSource(
        subject_id=1, code="P-1", where="subject P-1", info={}, session_label="baseline",
        session_date="2026-11-24", file_stamp="2026-11-24",
        recordings=[("R1", "complete"), ("R2", "on_nodes"), ("R3", "incomplete")],
        labels={"R1": "walk 1", "R2": "walk 2", "R3": ""},
        references={"R1": rr.ReferenceFile(bad, 0.0, "vicon ref.csv")})
    notes = rr.build_subject_report(src, tmp_path, {}).quality.notes
    assert "Trial “walk 2” (recording R2, still on the sensors) was not used: it is not " \
           "complete on the server." in notes, notes
    assert "Recording R3 (incomplete) was not used: it is not complete on the server." \
           in notes, notes
    # the reference named once, as chosen (not the server's ref.csv)
    assert ("Trial “walk 1” (recording R1): the reference could not be used — 'vicon "
            "ref.csv' is not a readable CSV file: no 'time' column; the first column must be "
            "'time' (seconds), then <Joint>_x,<Joint>_y,<Joint>_z[,<Joint>_state]") in notes, notes
