"""Agreement statistics against pingouin and hand-computed values."""

from __future__ import annotations

import io

import matplotlib.image as mpimg
import numpy as np
import pandas as pd
import pingouin as pg
import pytest

from engine.agreement import (
    agreement,
    agreement_levels,
    bland_altman_png,
    icc_a1,
    match_steps,
    pearson,
)
from engine.errors import InputError, InsufficientDataError
from engine.gait import Step


def _pg_icc2(a: np.ndarray, b: np.ndarray) -> float:
    n = len(a)
    df = pd.DataFrame({"target": np.tile(np.arange(n), 2),
                       "rater": np.repeat(["m", "r"], n),
                       "y": np.concatenate([a, b])})
    t = pg.intraclass_corr(data=df, targets="target", raters="rater", ratings="y")
    return _icc2_row(t)


def _icc2_row(t: pd.DataFrame) -> float:
    """pingouin's ICC2 row (renamed "ICC(A,1)" in pingouin ≥ 0.6)."""
    t = t.set_index("Type")
    return float(t.loc["ICC2" if "ICC2" in t.index else "ICC(A,1)", "ICC"])


@pytest.mark.parametrize("seed, bias, noise", [(0, 0.0, 0.02), (1, 0.03, 0.05), (2, -0.01, 0.2)])
def test_r_and_icc_match_pingouin(seed: int, bias: float, noise: float) -> None:
    rng = np.random.default_rng(seed)
    ref = rng.normal(0.72, 0.05, 60)
    meas = ref + bias + rng.normal(0, noise, 60)
    ag = agreement(meas, ref)
    c = pg.corr(meas, ref)
    assert ag.r == pytest.approx(float(c["r"].iloc[0]), abs=1e-12)
    pcol = "p_val" if "p_val" in c.columns else "p-val"
    assert ag.p == pytest.approx(float(c[pcol].iloc[0]), rel=1e-6)
    assert ag.icc_a1 == pytest.approx(_pg_icc2(meas, ref), abs=1e-10)
    d = meas - ref
    assert ag.bias == pytest.approx(d.mean())
    assert ag.rpc == pytest.approx(1.96 * d.std(ddof=1))
    assert ag.cv_pct == pytest.approx(100 * d.std(ddof=1) / np.mean((meas + ref) / 2))
    assert ag.n == 60
    lo, hi = ag.limits_of_agreement
    assert hi - lo == pytest.approx(2 * ag.rpc)


def test_icc_three_raters_matches_pingouin() -> None:
    rng = np.random.default_rng(9)
    t = rng.normal(0, 1, 20)
    Y = np.column_stack([t, t + 0.3 + rng.normal(0, 0.2, 20), t + rng.normal(0, 0.5, 20)])
    df = pd.DataFrame({"target": np.tile(np.arange(20), 3), "rater": np.repeat([0, 1, 2], 20),
                       "y": Y.T.ravel()})
    ref = pg.intraclass_corr(data=df, targets="target", raters="rater", ratings="y")
    assert icc_a1(Y) == pytest.approx(_icc2_row(ref), abs=1e-10)


def test_icc_penalises_bias_unlike_r() -> None:
    x = np.linspace(0.5, 0.9, 30)
    ag = agreement(x + 0.2, x)
    assert ag.r == pytest.approx(1.0)
    assert ag.icc_a1 < 0.6
    assert agreement(x, x).icc_a1 == pytest.approx(1.0)


def test_match_steps_by_time_and_side() -> None:
    ref = [Step("L", 1.0, 0.7, 0.1, 0.55), Step("R", 1.55, 0.72, 0.1, 0.55),
           Step("L", 2.1, 0.71, 0.1, 0.55)]
    meas = [Step("R", 1.58, 0.7, 0.1, 0.5), Step("L", 2.05, 0.7, 0.1, 0.5),
            Step("L", 1.2, 0.7, 0.1, 0.5), Step("L", 3.0, 0.7, 0.1, 0.5)]
    pairs = match_steps(meas, ref, max_dt_s=0.25)
    assert [(m.time_s, r.time_s) for m, r in pairs] == [(1.2, 1.0), (1.58, 1.55), (2.05, 2.1)]
    assert match_steps(meas, ref, max_dt_s=0.1) == [(meas[0], ref[1]), (meas[1], ref[2])]


def test_three_levels() -> None:
    rng = np.random.default_rng(4)
    trials = {}
    for s in range(8):
        L0 = rng.normal(0.72, 0.05)
        trs = []
        for _ in range(3):
            ref = [Step("L" if k % 2 else "R", 0.55 * k, L0 + rng.normal(0, 0.02), 0.1, 0.55)
                   for k in range(1, 12)]
            meas = [Step(r.side, r.time_s + 0.01, r.length_m + (0.02 if r.side == "R" else 0)
                         + rng.normal(0, 0.01), 0.1, 0.55) for r in ref]
            trs.append((meas, ref))
        trials[f"S{s}"] = trs
    lv = agreement_levels(trials, "length_m")
    assert set(lv) == {"L", "R", "AV L", "AV R", "AV AVG"}
    assert lv["L"].n == 8 * 3 * 6 and lv["R"].n == 8 * 3 * 5 and lv["AV AVG"].n == 8
    assert lv["R"].bias == pytest.approx(0.02, abs=0.005)
    assert abs(lv["L"].bias) < 0.005
    assert lv["AV AVG"].icc_a1 > lv["R"].icc_a1


def test_bland_altman_png() -> None:
    rng = np.random.default_rng(0)
    ref = rng.normal(70, 5, 40)
    png = bland_altman_png(ref + rng.normal(1, 2, 40), ref, "Step length L", "cm")
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    img = mpimg.imread(io.BytesIO(png))
    assert img.shape[0] > 200 and img.shape[1] > 300
    assert img[..., :3].std() > 0.05  # not blank


def test_bad_input() -> None:
    with pytest.raises(InputError):
        agreement([1, 2, 3], [1, 2])
    with pytest.raises(InsufficientDataError):
        agreement([1, np.nan], [1, 2])
    with pytest.raises(InputError):
        icc_a1(np.ones(5))
    r, p = pearson([1, 1, 1], [1, 2, 3])
    assert np.isnan(r) and np.isnan(p)


def test_match_events_pairs_same_side_and_kind() -> None:
    from engine.agreement import match_events
    from engine.gait import GaitEvent
    from engine.io.markers import MarkerEvent

    ref = [MarkerEvent(1.00, "L", "foot_strike", "Foot Strike"),
           MarkerEvent(1.05, "R", "foot_off", "Foot Off"),
           MarkerEvent(1.55, "R", "foot_strike", "Foot Strike"),
           MarkerEvent(1.20, "", "general", "Event")]  # no side: never paired
    det = [GaitEvent("L", "foot_strike", 1.01), GaitEvent("R", "foot_off", 1.02),
           GaitEvent("L", "foot_off", 1.04),  # only a right foot off nearby: unpaired
           GaitEvent("R", "foot_strike", 1.80)]  # 0.25 s late: beyond max_dt_s
    pairs = match_events(det, ref)
    assert [(m.side, m.kind, r.time_s) for m, r in pairs] == [
        ("L", "foot_strike", 1.00), ("R", "foot_off", 1.05)]
    assert [round(m.time_s - r.time_s, 3) for m, r in pairs] == [0.01, -0.03]
    assert len(match_events(det, ref, max_dt_s=0.3)) == 3
