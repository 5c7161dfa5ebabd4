"""A validation study's report (``engine.report.study``): the paper's two tables with every
row of the study in its unit, the Bland–Altman plots with their text, the notes; the PDF
rendered to PNG (title, tables and plots on its pages); the three file types by suffix."""

from __future__ import annotations

import base64
import re
import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from engine.agreement import AgreementStudy
from engine.errors import InputError
from engine.report.study import StudyReport, render_study_html, render_study_pdf, save_study_report
from tests.engine.test_agreement_study import _study

needs_poppler = pytest.mark.skipif(shutil.which("pdftoppm") is None,
                                   reason="poppler-utils not installed")


def _report() -> StudyReport:
    trials = _study()
    # one walk whose files do not start together: no step matches, named in the notes
    from types import SimpleNamespace

    from engine.agreement import StudyTrial

    t = trials["P0"][0]
    trials["P0"][0] = StudyTrial(t.measured_steps, [
        SimpleNamespace(**{**vars(s), "time_s": s.time_s + 5.0}) for s in t.reference_steps],
        name="P0 walk 0")
    return StudyReport(AgreementStudy().fit(trials), system="Kinect avenue",
                       reference="Vicon", basis=["Project Knee OA: 4 subjects, 12 trials"],
                       notes=["P9 walk 2: the reference could not be used — no steps"])


def test_html_has_both_tables_every_row_and_the_plots() -> None:
    report = _report()
    html = render_study_html(report)
    assert "<h1>Agreement with a reference system</h1>" in html
    t1 = html[html.index("Table 1"):html.index("Table 2")]
    t2 = html[html.index("Table 2"):html.index("Bland–Altman plots")]
    assert "AV walking speed (cm/s)" in t1 and "Step time L (s)" in t1
    assert "Step width R (cm)" in t2 and "AV stride length AVG (cm)" in t2
    assert "Step width" not in t1
    labels = re.findall(r'<th scope="row" class="l rh">([^<]+)</th>', html)
    assert labels == [r.label for r in report.study.rows_]
    assert html.count(">Kinect avenue</th>") == 2 and html.count(">Vicon</th>") == 2
    # the step-width row in cm: its bias is the 1 cm offset the study's walks have
    row = re.search(r"Step width L \(cm\)</th>((?:<td>[^<]*</td>\s*)+)", html)
    assert row is not None
    cells = re.findall(r"<td>([^<]*)</td>", row[1])
    assert float(cells[7]) == pytest.approx(1.0, abs=0.3)
    # one Bland–Altman plot per parameter, decodable, with its numbers in its text
    figs = re.findall(r'<img src="data:image/png;base64,([^"]+)" alt="([^"]+)"><figcaption>'
                      r'([^<]+)</figcaption>', html)
    assert [c.split(":")[1].split("(")[0].strip() for _, _, c in figs] == [
        "step time", "stride length", "step length", "step width"]
    for uri, alt, _ in figs:
        img = cv2.imdecode(np.frombuffer(base64.b64decode(uri), np.uint8), cv2.IMREAD_COLOR)
        assert img is not None and img.std() > 10
        assert "bias" in alt and "limits of agreement" in alt
    assert "P0 walk 0: none of its steps matched the reference" in html
    # a bias that rounds to zero has no sign (the step times' read "-0.000")
    assert not re.search(r"<td>-0\.0+</td>", html)
    assert re.search(r"<td>0\.000</td>", html)
    assert "P9 walk 2: the reference could not be used" in html
    assert "Project Knee OA: 4 subjects, 12 trials" in html
    # the console's fragment: no page around it
    frag = render_study_html(report, standalone=False)
    assert not frag.lstrip().startswith("<!doctype") and "Table 2" in frag


@needs_poppler
def test_pdf_shows_title_tables_and_plots(tmp_path: Path, artifacts_dir: Path) -> None:
    pdf = render_study_pdf(_report())
    assert pdf.startswith(b"%PDF")
    f = tmp_path / "study.pdf"
    f.write_bytes(pdf)
    text = subprocess.run(["pdftotext", "-layout", str(f), "-"], capture_output=True,
                          text=True, check=True, timeout=60).stdout
    for want in ("Agreement with a reference system", "Table 1", "Table 2",
                 "AV step width AVG (cm)", "ICC(A,1)", "Bland–Altman: step width"):
        assert want in text, want
    subprocess.run(["pdftoppm", "-r", "40", "-png", str(f), str(tmp_path / "p")], check=True,
                   timeout=60)
    pages = [cv2.imread(str(p)) for p in sorted(tmp_path.glob("p-*.png"))]
    assert pages and all(p.shape[1] > p.shape[0] for p in pages)  # landscape
    shutil.copy(sorted(tmp_path.glob("p-*.png"))[0], artifacts_dir / "study_report_page1.png")
    # the plots are drawn: coloured (blue points, red limits) pixels on some page
    blue = sum(int(((p[..., 0] > 150) & (p[..., 2] < 120)).sum()) for p in pages)
    assert blue > 50


def test_saved_by_suffix(tmp_path: Path) -> None:
    report = _report()
    assert save_study_report(report, tmp_path / "s.csv").read_text() == report.study.csv()
    assert "<table" in save_study_report(report, tmp_path / "s.html").read_text()
    with pytest.raises(InputError, match=r"\.html, \.pdf or \.csv"):
        save_study_report(report, tmp_path / "s.docx")
