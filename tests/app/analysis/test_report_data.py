"""The report data the server builds from analyses: units and facts a clinician reads."""

from __future__ import annotations

import numpy as np

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
