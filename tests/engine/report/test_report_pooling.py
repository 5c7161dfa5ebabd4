"""Session walking speed and cadence are pooled over all steps of all trials.

The report averaged the trials' values, each trial with equal weight: a two-step walk
moved the session's speed as much as a twenty-step one. A clinician expects the session's
speed to be Σ step lengths / Σ step times over every step (the gait JSON's per-trial
definition), and cadence 60 · steps / Σ step times.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from engine.report.render import (
    ReportData,
    TrialData,
    pace,
    render_html,
    render_pdf,
    spatiotemporal_table,
)


def _walk(name: str, n: int, length: float, duration: float) -> TrialData:
    steps: list[dict[str, Any]] = []
    t = 0.0
    for i in range(n):
        t += duration
        steps.append({"side": "LR"[i % 2], "time_s": t, "length_m": length,
                      "width_m": 0.1, "duration_s": duration})
    # the gait engine's per-trial summary (Σ lengths / Σ times; 60 · steps / Σ times)
    summary = {"walking_speed_m_s": length / duration, "cadence_steps_min": 60.0 / duration}
    return TrialData(name, {"events": [], "steps": steps, "strides": [], "summary": summary})


LONG = _walk("long walk", 20, 0.70, 0.50)   # 1.40 m/s, 120 steps/min, 10 s
SHORT = _walk("short walk", 2, 0.40, 0.80)  # 0.50 m/s,  75 steps/min, 1.6 s
POOLED_SPEED = (20 * 0.70 + 2 * 0.40) / (20 * 0.50 + 2 * 0.80)  # 1.276, not (1.4+0.5)/2
POOLED_CADENCE = 60.0 * 22 / (20 * 0.50 + 2 * 0.80)            # 113.8, not 97.5


def test_session_speed_and_cadence_are_pooled_over_steps_not_averaged_over_trials() -> None:
    rows = {r.label: r for r in spatiotemporal_table([LONG, SHORT])}
    speed, cadence = rows["Walking speed"], rows["Cadence"]
    assert speed.mean == pytest.approx(POOLED_SPEED)
    assert cadence.mean == pytest.approx(POOLED_CADENCE)
    assert speed.mean != pytest.approx((1.4 + 0.5) / 2, abs=0.05)
    # N = trials; SD and CV between the trials' own values, relative to the pooled value
    assert speed.n == 2 and cadence.n == 2
    assert speed.sd == pytest.approx(np.std([1.4, 0.5], ddof=1))
    assert speed.cv_pct == pytest.approx(100 * np.std([1.4, 0.5], ddof=1) / POOLED_SPEED)
    # one trial: the pooled value is that trial's own
    one = {r.label: r for r in spatiotemporal_table([SHORT])}
    assert one["Walking speed"].mean == pytest.approx(0.5)
    assert one["Cadence"].mean == pytest.approx(75.0)


def test_steps_without_a_length_count_for_cadence_only() -> None:
    tr = _walk("w", 4, 0.6, 0.5)
    tr.result["steps"][0]["length_m"] = None
    p = pace([tr])
    assert p.n_steps == 4 and p.cadence_steps_min == pytest.approx(120.0)
    assert p.speed_m_s == pytest.approx(1.2)  # 3 × 0.6 m over 3 × 0.5 s


def test_without_step_times_the_trials_summary_values_are_used() -> None:
    tr = _walk("w", 4, 0.6, 0.5)
    for s in tr.result["steps"]:
        s["duration_s"] = None
    rows = {r.label: r for r in spatiotemporal_table([tr])}
    assert rows["Walking speed"].mean == pytest.approx(1.2)


def _row(html: str, label: str) -> list[str]:
    m = re.search(rf"<th[^>]*>{label}</th>(.*?)</tr>", html, re.S)
    assert m is not None, label
    return re.findall(r"<t[dh][^>]*>\s*([^<]*?)\s*</t[dh]>", m.group(1))


@pytest.mark.skipif(shutil.which("pdftotext") is None, reason="poppler-utils not installed")
def test_html_and_pdf_show_the_pooled_session_and_the_per_trial_values(tmp_path: Path) -> None:
    data = ReportData("P-201", [LONG, SHORT])
    html = render_html(data, standalone=False)
    speed, cadence = _row(html, "Walking speed"), _row(html, "Cadence")
    assert speed[2] == f"{POOLED_SPEED:.2f}" == "1.28"
    assert cadence[2] == f"{POOLED_CADENCE:.1f}" == "113.8"
    assert _row(html, "long walk")[:4] == ["20", "10.00", "1.40", "120.0"]
    assert _row(html, "short walk")[:4] == ["2", "1.60", "0.50", "75.0"]
    assert "pooled over all steps of all trials" in html
    f = tmp_path / "r.pdf"
    f.write_bytes(render_pdf(data))
    text = subprocess.run(["pdftotext", "-layout", str(f), "-"], capture_output=True,
                          text=True, check=True, timeout=60).stdout
    lines = {ln.split()[0] + " " + ln.split()[1]: ln.split() for ln in text.splitlines()
             if len(ln.split()) > 3}
    assert lines["Walking speed"][4] == "1.28", lines["Walking speed"]
    assert "113.8" in lines["Cadence both"], lines["Cadence both"]
    assert lines["long walk"][2:6] == ["20", "10.00", "1.40", "120.0"]
    assert lines["short walk"][2:6] == ["2", "1.60", "0.50", "75.0"]
    assert "pooled over all steps of all trials" in " ".join(text.split())
