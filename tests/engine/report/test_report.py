"""Gait report: table statistics against hand computation; HTML and PDF content."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from engine.errors import InputError, InsufficientDataError
from engine.report.normative import (
    DEFAULT_NORMATIVE_RANGES,
    load_normative_ranges,
    save_normative_ranges,
)
from engine.report.plots import plot_bland_altman
from engine.report.render import (
    AgreementRow,
    QualityInfo,
    ReportData,
    TrialData,
    render_html,
    render_pdf,
    save_report,
    spatiotemporal_table,
)


def _trial(name: str, rng: np.random.Generator, left_len: float = 0.70,
           right_len: float = 0.64) -> TrialData:
    steps, strides, placements = [], [], []
    x, t = 0.0, 0.0
    for i in range(12):
        side = "L" if i % 2 == 0 else "R"
        length = (left_len if side == "L" else right_len) + rng.normal(0, 0.01)
        dur = 0.55 + rng.normal(0, 0.01)
        x += length
        t += dur
        steps.append({"side": side, "time_s": t, "length_m": length,
                      "width_m": 0.10 + rng.normal(0, 0.01), "duration_s": dur})
        placements.append({"side": side, "time_s": t,
                           "position": [x, 0.05 if side == "L" else -0.05, 0.0]})
    for i in range(2, len(steps)):
        strides.append({"side": steps[i]["side"], "time_s": steps[i]["time_s"],
                        "length_m": steps[i]["length_m"] + steps[i - 1]["length_m"],
                        "duration_s": steps[i]["duration_s"] + steps[i - 1]["duration_s"]})
    speed = sum(s["length_m"] for s in steps) / sum(s["duration_s"] for s in steps)
    times = np.linspace(0, t, 200)
    result = {
        "events": [{"side": s["side"], "kind": "foot_strike", "time_s": s["time_s"]}
                   for s in steps],
        "steps": steps, "strides": strides,
        "summary": {"walking_speed_m_s": speed, "cadence_steps_min": 60 / 0.55,
                    "stance_pct_L": 61.0, "stance_pct_R": 60.0, "double_support_pct": 21.0},
    }
    return TrialData(name, result, placements, times,
                     {"L": 0.08 + 0.05 * np.sin(times * 6), "R": 0.08 + 0.05 * np.cos(times * 6)})


def _data() -> ReportData:
    rng = np.random.default_rng(0)
    trials = [_trial(f"walk {i + 1}", rng) for i in range(3)]
    ba = plot_bland_altman(rng.normal(70, 5, 40), rng.normal(70, 5, 40), "Step length", "cm")
    return ReportData(
        subject_code="P-017", trials=trials, session_label="Baseline",
        session_date="2026-11-20", subject_info={"Height": "1.72 m", "Sex": "F"},
        quality=QualityInfo(sensors_used=["S1", "S2"], joints_tracked_pct=72.0,
                            clock_offsets_ms={"S1": 0.3, "S2": -0.2},
                            clock_uncertainty_ms={"S1": 0.2, "S2": 3.5},
                            calibration_residuals_mm={"S1": 2.1, "S2": 14.0}),
        agreement=[AgreementRow("Step length L", "steps", 40, 0.83, 1e-5, 0.4, 5.9, 4.1, 0.83,
                                "cm")],
        agreement_figures=[("Bland–Altman: step length", ba)],
    )


def test_table_matches_hand_computation():
    data = _data()
    rows = spatiotemporal_table(data.trials)
    by = {(r.label, r.side): r for r in rows}
    left = [s["length_m"] for t in data.trials for s in t.result["steps"] if s["side"] == "L"]
    right = [s["length_m"] for t in data.trials for s in t.result["steps"] if s["side"] == "R"]
    r_l = by[("Step length", "L")]
    assert r_l.n == len(left)
    assert r_l.mean == pytest.approx(100 * np.mean(left))
    assert r_l.sd == pytest.approx(100 * np.std(left, ddof=1))
    both = by[("Step length", "")]
    assert both.mean == pytest.approx(100 * np.mean(left + right))
    ml, mr = np.mean(left), np.mean(right)
    expected_asym = 100 * abs(ml - mr) / ((ml + mr) / 2)
    assert both.asymmetry_pct == pytest.approx(expected_asym)
    # stance only given per side in the summary: both-sides row pools them
    assert by[("Stance", "")].mean == pytest.approx(60.5)
    assert ("Swing", "") not in by  # no data, no row


def test_normative_flag():
    data = _data()
    for t in data.trials:
        for s in t.result["steps"]:
            s["width_m"] = 0.30
    rows = {(r.label, r.side): r for r in spatiotemporal_table(data.trials)}
    assert rows[("Step width", "")].flag == "above"
    assert rows[("Step length", "")].flag == ""


def test_html_contains_tables_figures_and_quality_notes():
    html = render_html(_data())
    assert "P-017" in html and "Spatiotemporal parameters" in html
    assert html.count("data:image/png;base64,") >= 4  # placements, ankles, steps, BA
    assert "clock uncertainty 3.5 ms" in html
    assert "calibration residual 14.0 mm" in html
    assert "Agreement with the reference system" in html
    assert "Bohannon" in html  # normative source cited


def test_html_escapes_user_text():
    data = _data()
    data.subject_code = "<script>alert(1)</script>"
    assert "<script>alert(1)" not in render_html(data)


def test_bad_input():
    with pytest.raises(InsufficientDataError):
        render_html(ReportData("X", []))
    with pytest.raises(InputError):
        render_html(ReportData("X", [TrialData("t", {"nothing": 1})]))
    with pytest.raises(InputError):
        save_report(_data(), "report.docx")


def test_normative_round_trip_and_errors(tmp_path: Path):
    p = tmp_path / "n.json"
    save_normative_ranges(list(DEFAULT_NORMATIVE_RANGES), p)
    assert load_normative_ranges(p) == list(DEFAULT_NORMATIVE_RANGES)
    p.write_text('[{"parameter": "x", "low": 2, "high": 1, "source": "s"}]')
    with pytest.raises(InputError, match="low > high"):
        load_normative_ranges(p)


@pytest.mark.skipif(shutil.which("pdftoppm") is None, reason="poppler-utils not installed")
def test_pdf_renders_to_png_with_content(tmp_path: Path, artifacts_dir: Path):
    pdf = render_pdf(_data())
    assert pdf[:5] == b"%PDF-"
    pdf_path = artifacts_dir / "gait_report.pdf"
    pdf_path.write_bytes(pdf)
    text = subprocess.run(["pdftotext", "-layout", str(pdf_path), "-"], capture_output=True,
                          text=True, check=True).stdout
    for needle in ("Gait report", "P-017", "Spatiotemporal parameters", "Step length",
                   "Walking speed", "Data quality", "Agreement with the reference system"):
        assert needle in text, needle
    images = subprocess.run(["pdfimages", "-list", str(pdf_path)], capture_output=True,
                            text=True, check=True).stdout.strip().splitlines()[2:]
    assert len(images) >= 4
    subprocess.run(["pdftoppm", "-png", "-r", "60", str(pdf_path), str(tmp_path / "page")],
                   check=True)
    pages = sorted(tmp_path.glob("page*.png"))
    assert pages
    import cv2

    first = cv2.imread(str(pages[0]))
    shutil.copy(pages[0], artifacts_dir / "gait_report_page1.png")
    # a rendered page is not blank: ink covers a real fraction of it
    ink = (first.mean(axis=2) < 200).mean()
    assert 0.02 < ink < 0.6


def test_pdf_fetches_nothing_but_its_own_data_uris(monkeypatch: pytest.MonkeyPatch,
                                                   tmp_path: Path) -> None:
    """Whatever reached the page (here an image and a stylesheet on a local web server and
    a local file, planted in the rendered HTML), the PDF renderer asks no address and
    reads no file; the report's own data: plots are still drawn."""
    import http.server
    import threading

    from engine.report import render

    asked: list[str] = []

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            asked.append(self.path)
            self.send_response(404)
            self.end_headers()

        def log_message(self, *args: object) -> None:
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    secret = tmp_path / "secret.png"
    secret.write_bytes(b"not an image")
    base = f"http://127.0.0.1:{server.server_address[1]}"
    plain = render.render_html

    def planted(data: ReportData, standalone: bool = False) -> str:
        html = plain(data, standalone=standalone)
        return html.replace("</body>", f'<img src="{base}/img.png" alt=""><img src="'
                            f'{secret.as_uri()}" alt=""><link rel="stylesheet" href="'
                            f'{base}/x.css"></body>')

    monkeypatch.setattr(render, "render_html", planted)
    try:
        pdf = render_pdf(_data())
    finally:
        server.shutdown()
    assert asked == []
    assert pdf.startswith(b"%PDF") and pdf.count(b"/Subtype /Image") >= 3
