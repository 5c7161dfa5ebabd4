"""A validation study's tables (``engine.agreement.AgreementStudy``): the paper's rows and
levels from known steps, each row's statistics as ``agreement`` gives them on the values
the level should pair, and clear errors where nothing can be computed."""

from __future__ import annotations

import csv
import io
from types import SimpleNamespace

import numpy as np
import pytest

from engine.agreement import (
    STUDY_CSV_COLUMNS,
    AgreementStudy,
    StudyTrial,
    agreement,
)
from engine.errors import InputError, InsufficientDataError


def _walk(rng: np.random.Generator, step: float, width: float, t0: float, n: int = 8,
          offset: float = 0.0) -> tuple[list[SimpleNamespace], list[SimpleNamespace],
                                        list[SimpleNamespace], list[SimpleNamespace]]:
    """Reference and measured steps and strides of one walk: the measured ones are the
    reference's plus ``offset`` (m) on length and width and a little noise, 20 ms late."""
    ref_steps, meas_steps, ref_strides, meas_strides = [], [], [], []
    for k in range(n):
        side = "LR"[k % 2]
        t = t0 + 0.55 * k
        length = step + rng.normal(0, 0.03)
        w = width + rng.normal(0, 0.02)
        dur = 0.55 + rng.normal(0, 0.02)
        ref_steps.append(SimpleNamespace(side=side, time_s=t, length_m=length, width_m=w,
                                         duration_s=dur))
        meas_steps.append(SimpleNamespace(
            side=side, time_s=t + 0.02, length_m=length + offset + rng.normal(0, 0.01),
            width_m=w + offset + rng.normal(0, 0.01), duration_s=dur + rng.normal(0, 0.005)))
        if k >= 2:
            ref_strides.append(SimpleNamespace(side=side, time_s=t, length_m=2 * length))
            meas_strides.append(SimpleNamespace(side=side, time_s=t + 0.02,
                                                length_m=2 * length + offset))
    return meas_steps, ref_steps, meas_strides, ref_strides


def _study(n_subjects: int = 4, offset: float = 0.01) -> dict[str, list[StudyTrial]]:
    rng = np.random.default_rng(7)
    out: dict[str, list[StudyTrial]] = {}
    for s in range(n_subjects):
        step, width = 0.65 + 0.03 * s, 0.10 + 0.01 * s
        trials = []
        for w in range(3):
            ms, rs, mst, rst = _walk(rng, step, width, 10.0 * w, offset=offset)
            speed = step / 0.55
            trials.append(StudyTrial(ms, rs, mst, rst, speed + 0.01, speed, f"P{s} walk {w}"))
        out[f"P{s}"] = trials
    return out


def test_rows_follow_the_papers_tables_and_levels() -> None:
    study = AgreementStudy().fit(_study())
    labels = [r.label for r in study.rows_]
    assert labels[0] == "AV walking speed (cm/s)"
    assert labels[1:6] == ["Step time L (s)", "Step time R (s)", "AV step time L (s)",
                           "AV step time R (s)", "AV step time AVG (s)"]
    assert "AV step width R (cm)" in labels and "Stride length L (cm)" in labels
    assert {r.table for r in study.rows_ if r.parameter in ("walking speed", "step time")} == {1}
    assert {r.table for r in study.rows_ if "length" in r.parameter
            or r.parameter == "step width"} == {2}
    assert len(labels) == 1 + 4 * 5
    assert study.n_subjects_ == 4 and study.n_trials_ == 12 and study.unmatched_ == []


def test_each_level_pairs_the_values_it_should() -> None:
    trials = _study()
    study = AgreementStudy().fit(trials)
    rows = {r.label: r for r in study.rows_}
    # single steps of one side: every left step of every trial, matched in time
    left = [(m.width_m, r.width_m) for trs in trials.values() for t in trs
            for m, r in zip(t.measured_steps, t.reference_steps, strict=True) if m.side == "L"]
    want = agreement(*np.array(left).T)
    got = rows["Step width L (cm)"]
    assert got.agreement == want
    shown = got.shown()
    assert shown.bias == pytest.approx(100 * want.bias) and shown.icc_a1 == want.icc_a1
    assert shown.bias == pytest.approx(1.0, abs=0.3)  # the 1 cm offset, in cm
    # subject averages over both sides: one value per subject from all its steps
    av = [(np.mean([s.length_m for t in trs for s in t.measured_steps]),
           np.mean([s.length_m for t in trs for s in t.reference_steps]))
          for trs in trials.values()]
    assert rows["AV step length AVG (cm)"].agreement == agreement(*np.array(av).T)
    assert rows["AV walking speed (cm/s)"].shown().bias == pytest.approx(1.0)
    # the Bland–Altman points are the matched single steps of both sides
    m, r = study.pairs_["step width"]
    assert len(m) == len(r) == sum(len(t.measured_steps) for trs in trials.values()
                                   for t in trs)


def test_csv_has_every_row_in_its_unit() -> None:
    study = AgreementStudy().fit(_study())
    table = list(csv.DictReader(io.StringIO(study.csv())))
    assert tuple(table[0]) == STUDY_CSV_COLUMNS
    assert len(table) == len(study.rows_)
    width = next(t for t in table if t["parameter"] == "step width" and t["level"] == "L")
    assert width["unit"] == "cm" and float(width["bias"]) == pytest.approx(1.0, abs=0.3)


def test_two_subjects_give_single_steps_but_no_subject_averages() -> None:
    study = AgreementStudy().fit(dict(list(_study().items())[:2]))
    assert all(not r.level.startswith("AV") for r in study.rows_)
    assert [r.level for r in study.rows_ if r.parameter == "step length"] == ["L", "R"]


def test_walks_that_do_not_start_together_are_named_and_nothing_is_computed() -> None:
    trials = _study(n_subjects=2)
    # the reference 5 s later on every trial: no step matches, and walking speed needs
    # three subjects
    late = {k: [StudyTrial(t.measured_steps,
                           [SimpleNamespace(**{**vars(s), "time_s": s.time_s + 5.0})
                            for s in t.reference_steps], name=t.name) for t in trs]
            for k, trs in trials.items()}
    with pytest.raises(InsufficientDataError, match="at least three steps must match"):
        AgreementStudy().fit(late)
    # one trial late among good ones: computed, and that trial named
    mixed = {**trials, "P1": [*late["P1"][:1], *trials["P1"][1:]]}
    study = AgreementStudy().fit(mixed)
    assert study.unmatched_ == ["P1 walk 0"]
    with pytest.raises(InputError, match="max_dt_s"):
        AgreementStudy(max_dt_s=0).fit(trials)


def test_steps_without_a_value_are_left_out_not_fatal() -> None:
    """Gait JSON writes a value a step does not have as None (NaN in the engine): such a
    step leaves its pair and its subject's average, and the rest is computed as before."""
    trials = _study()
    holes = {}
    for k, trs in trials.items():
        first = trs[0]
        steps = [SimpleNamespace(**{**vars(s), "width_m": None}) if i == 0 else s
                 for i, s in enumerate(first.measured_steps)]
        ref = [SimpleNamespace(**{**vars(s), "duration_s": float("nan")}) if i == 1 else s
               for i, s in enumerate(first.reference_steps)]
        holes[k] = [StudyTrial(steps, ref, first.measured_strides, first.reference_strides,
                               first.measured_speed_m_s, first.reference_speed_m_s,
                               first.name), *trs[1:]]
    study = AgreementStudy().fit(holes)
    rows = {r.label: r for r in study.rows_}
    whole = AgreementStudy().fit(trials)
    full = {r.label: r for r in whole.rows_}
    assert rows["Step width L (cm)"].agreement.n == full["Step width L (cm)"].agreement.n - 4
    assert rows["Step time R (s)"].agreement.n == full["Step time R (s)"].agreement.n - 4
    assert np.isfinite(rows["AV step width AVG (cm)"].agreement.bias)
    m, r = study.pairs_["step width"]
    assert np.isfinite(m).all() and np.isfinite(r).all()
    assert len(m) == len(whole.pairs_["step width"][0]) - 4
