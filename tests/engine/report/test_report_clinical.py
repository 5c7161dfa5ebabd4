"""The report as a clinician reads it: every trial visible, warnings where data are thin,
sources per normative band, numbers that match the recordings.

Content checks on the HTML and on the PDF's text and pages (no pixel comparisons).
"""

from __future__ import annotations

import base64
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from engine.report.render import ReportData, TrialData, render_html, render_pdf
from tests.engine.report.test_report import _trial


@pytest.fixture
def drawn(monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    """The matplotlib figures the report's plots render, in order."""
    from engine.report import plots

    seen: list[Any] = []
    real = plots.figure_png

    def keep(fig: Any, dpi: int = 130) -> bytes:
        seen.append(fig)
        return real(fig, dpi)

    monkeypatch.setattr(plots, "figure_png", keep)
    return seen


needs_poppler = pytest.mark.skipif(shutil.which("pdftoppm") is None,
                                   reason="poppler-utils not installed")


def _trials(n: int, seed: int = 0) -> list[TrialData]:
    rng = np.random.default_rng(seed)
    return [_trial(f"R20261124-1000{i:02d}-abcd (S1, S2, S3, S4, S5, S6)", rng)
            for i in range(n)]


def _images(html: str) -> list[tuple[str, np.ndarray]]:
    """(caption, decoded image) of every figure of the HTML report."""
    out = []
    for uri, cap in re.findall(r'<img src="data:image/png;base64,([^"]+)" alt="[^"]*">'
                               r'<figcaption>([^<]*)</figcaption>', html):
        img = cv2.imdecode(np.frombuffer(base64.b64decode(uri), np.uint8), cv2.IMREAD_COLOR)
        out.append((cap, img))
    return out


def _pdf_pages(pdf: bytes, tmp: Path) -> tuple[str, list[np.ndarray]]:
    f = tmp / "r.pdf"
    f.write_bytes(pdf)
    text = subprocess.run(["pdftotext", "-layout", str(f), "-"], capture_output=True,
                          text=True, check=True, timeout=60).stdout
    subprocess.run(["pdftoppm", "-r", "40", "-png", str(f), str(tmp / "p")], check=True,
                   timeout=60)
    pages = [cv2.imread(str(p)) for p in sorted(tmp.glob("p-*.png"))]
    return text, pages


@needs_poppler
def test_many_trials_every_foot_placement_panel_fits_a_page(tmp_path: Path,
                                                            artifacts_dir: Path) -> None:
    """14 trials: the top view used to be one figure taller than the page (trials 10-14
    cut off in the PDF, and a page left blank under the 'Plots' heading)."""
    data = ReportData("P-100", _trials(14))
    html = render_html(data)
    tops = [(c, img) for c, img in _images(html) if c.startswith("Foot placements")]
    assert len(tops) == 3, [c for c, _ in tops]
    assert "trials 1–6 of 14" in tops[0][0] and "trials 13–14 of 14" in tops[2][0]
    for cap, img in tops:
        h, w = img.shape[:2]
        # printed 186 mm wide, it must fit the 267 mm the page leaves
        assert h / w * 186.0 < 260.0, (cap, h, w)
    text, pages = _pdf_pages(render_pdf(data), tmp_path)
    assert text.count("Foot placements seen from above") == 3
    shutil.copy(tmp_path / "r.pdf", artifacts_dir / "report_14_trials.pdf")
    for i, p in enumerate(pages):
        # no page holds only a heading (ink of a heading and footer alone is < 1 %)
        assert (p.min(axis=2) < 200).mean() > 0.01, f"page {i + 1} is nearly blank"


def test_a_trial_with_few_or_no_steps_is_named_in_the_notes() -> None:
    """A 2-step trial and an empty one among full trials used to pass in silence (the
    only warning looked at the total, 38 steps)."""
    trials = _trials(3)
    few = _trial("walk 4 (short)", np.random.default_rng(5))
    few.result["steps"] = few.result["steps"][:2]
    few.result["strides"] = []
    empty = TrialData("walk 5 (empty)", {"events": [], "steps": [], "strides": [],
                                         "summary": {}})
    html = render_html(ReportData("P-101", [*trials, few, empty]))
    assert "Trial walk 4 (short): only 2 steps" in html
    assert "Trial walk 5 (empty): no usable steps" in html
    assert "Step length" in html  # the report still renders its table
    full = render_html(ReportData("P-101", trials))
    assert "Trial " not in full and "steps were analysed" not in full


def test_fewer_than_ten_steps_per_side_is_flagged_even_with_more_in_total() -> None:
    """6 left and 6 right steps (12 in all; a real three-trial subject report had 7 and 6)
    used to give no warning although the note itself speaks of 10 steps per side."""
    t = _trial("walk 1", np.random.default_rng(2))
    assert len(t.result["steps"]) == 12
    html = render_html(ReportData("P-102", [t]))
    assert "Only 6 left and 6 right steps were analysed" in html


def test_each_normative_band_cites_its_source_and_population() -> None:
    """The bands used to stand without a reference number, their sources listed apart in
    alphabetical order with no population; Hollman 2011 (adults over 70) was labelled
    'healthy adults' and so read as a band for a 30-year-old."""
    html = render_html(ReportData("P-103", _trials(2)))
    foot = html[html.index("Normative bands are"):]
    # "[n] <population>: <first author> <initials> ..."
    cited = {n: author for n, _, author in
             re.findall(r"\[(\d)\] ([^;]+?): ([A-Z][a-z]+) [A-Z]+", foot)}
    assert len(cited) >= 3, foot[:600]
    row = re.search(r"<th[^>]*>Step length</th>.*?</tr>", html, re.S)
    assert row is not None
    num = re.search(r"<sup>\[(\d)\]</sup>", row.group(0))
    assert num is not None, "the step-length band has no source number"
    assert cited[num.group(1)] == "Hollman"
    assert re.search(rf"\[{num.group(1)}\] healthy adults over 70 y", foot)
    speed = re.search(r"<th[^>]*>Walking speed</th>.*?</tr>", html, re.S)
    assert speed is not None and "<sup>[1]</sup>" in speed.group(0)
    assert "CV = 100 · SD / mean" in html and "not matched to this subject's age" in html


def test_ankle_plot_marks_foot_placements_and_names_the_marks(
        drawn: list[Any]) -> None:
    """The crossing method's events ('placement', the published method and the console's
    default) were not drawn at all, and the dashed foot-strike lines had no legend."""
    from engine.report import plots

    seen = drawn
    t = np.linspace(0.0, 3.0, 100)
    h = {"L": 0.1 + 0.05 * np.sin(6 * t), "R": 0.1 + 0.05 * np.cos(6 * t)}
    for kind, name in (("placement", "foot placement"), ("foot_strike", "foot strike")):
        seen.clear()
        ev = [{"side": "LR"[i % 2], "kind": kind, "time_s": 0.5 * (i + 1)} for i in range(5)]
        assert plots.plot_ankle_heights(t, h, ev)[:4] == b"\x89PNG"
        ax = seen[0].axes[0]
        dashed = [ln for ln in ax.lines if ln.get_linestyle() == "--" and len(ln.get_xdata())]
        assert len(dashed) == 5, kind
        legend = ax.get_legend()
        assert legend is not None
        assert any(name in txt.get_text() for txt in legend.get_texts()), kind


def test_top_view_panels_share_one_scale_and_say_the_across_axis_is_stretched(
        drawn: list[Any]) -> None:
    """Each trial's panel was autoscaled (a 1.4 m trial drawn as long as a 3.5 m one) and
    nothing said that cm across and m along are not to scale."""
    from engine.report import plots

    seen = drawn
    long_walk = [{"side": "LR"[i % 2], "position": [0.7 * i, 0.05 * (-1) ** i, 0.0]}
                 for i in range(6)]
    short_walk = long_walk[:3]
    plots.plot_foot_placements([("long", long_walk), ("short", short_walk)])
    a, b = seen[0].axes[:2]
    assert a.get_xlim() == b.get_xlim()
    html = render_html(ReportData("P-104", _trials(2)))
    assert "across axis is stretched" in html


@needs_poppler
def test_non_latin_subject_code_in_title_and_footer(tmp_path: Path) -> None:
    """The page footer (subject code, page numbers) was set in the default serif font
    while the report is in DejaVu Sans; Latin letters with diacritics must survive."""
    code = "Zoë Łukasiewicz-Ødegård"
    pdf = render_pdf(ReportData(code, _trials(1)))
    text, _ = _pdf_pages(pdf, tmp_path)
    assert text.count(code) >= 2  # header and footer of page 1
    fonts = subprocess.run(["pdffonts", str(tmp_path / "r.pdf")], capture_output=True,
                           text=True, check=True).stdout
    assert "Serif" not in fonts, fonts


def test_footnote_says_what_n_counts_for_the_gait_cycle_phases() -> None:
    """Stance showed N = 6 for three trials (one value per trial and side) while the
    footnote said only speed and cadence were over trials."""
    html = render_html(ReportData("P-105", _trials(3)))
    row = re.search(r"<th[^>]*>Stance</th>\s*<th[^>]*>both</th>\s*<td>(\d+)</td>", html)
    assert row is not None and row.group(1) == "6"
    assert "stance, swing and double support over trials" in html
    assert "per side for stance and swing" in html


def test_step_plot_does_not_join_two_trials_into_one_line(
        drawn: list[Any]) -> None:
    """The per-step lines ran from the last step of one walk to the first of the next,
    drawn as if they were one walk."""

    seen = drawn
    html = render_html(ReportData("P-106", _trials(3)))
    assert "lines break between trials" in html
    steps_fig = next(f for f in seen if len(f.axes) == 3)
    for ax in steps_fig.axes:
        for line in ax.lines:
            y = np.asarray(line.get_ydata(), dtype=float)
            assert np.isnan(y).sum() == 2, ax.get_title()  # two breaks for three trials
            assert np.isfinite(y).sum() == 18  # 3 trials × 6 steps per side


def test_header_facts_stay_in_the_header_grid() -> None:
    """Four subject facts (height, sex, birth year, age) made a row of 8 cells under rows
    of 6: the age was pushed off to the right margin."""
    info = {"Height": "174 cm", "Sex": "female", "Born": "1958", "Age": "≈ 68 y"}
    html = render_html(ReportData("P-107", _trials(1), subject_info=info))
    meta = html[html.index('<div class="gr-facts">'):]
    meta = meta[:meta.index("</div>")]
    # one fact a row (its label the row header), the facts three abreast in three tables
    rows = re.findall(r"<tr>(.*?)</tr>", meta, re.S)
    assert len(rows) == 1 + 4 and meta.count("<table") == 3
    assert all(r.count("<td") == 1 and r.count('<th scope="row"') == 1 for r in rows), rows
    assert "≈ 68 y" in meta


@needs_poppler
def test_console_html_and_pdf_show_the_same_numbers(tmp_path: Path) -> None:
    """Both come from one template; every number of the console's tables is in the PDF."""
    from tests.engine.report.test_report import _data

    data = _data()
    fragment = render_html(data, standalone=False)
    text, pages = _pdf_pages(render_pdf(data), tmp_path)
    assert pages
    cells = re.findall(r"<td[^>]*>\s*(-?\d+\.\d+)", fragment)
    assert len(cells) > 60
    missing = [c for c in cells if c not in text]
    assert not missing, missing


def test_table_says_which_foot_left_and_right_rows_belong_to() -> None:
    """Whether 'left step length' ends or starts at the left foot was not said; labs use
    both conventions, so left/right asymmetry could be read mirrored."""
    html = render_html(ReportData("P-108", _trials(1)))
    assert "belongs to the foot placed at its end" in html
    assert "along and across the line of progression" in html


@needs_poppler
def test_a_page_break_never_parts_a_parameter_from_its_left_and_right_rows(
        tmp_path: Path) -> None:
    """With 70 trials the trials line pushes the table over the page: Stance's left row ended
    page 1 and its right row opened page 2 under no parameter name."""
    text, _ = _pdf_pages(render_pdf(ReportData("P-109", _trials(70))), tmp_path)
    pages = text.split("\f")
    split = False
    for k, page in enumerate(pages):
        lines = page.splitlines()
        heads = [i for i, ln in enumerate(lines) if re.match(r"\s*Parameter\s+Side\s+N", ln)]
        for i in heads:
            first = next(ln for ln in lines[i + 1:] if ln.strip())
            assert not re.match(r"\s*(left|right)\s+\d", first), (k + 1, first)
        split |= bool(heads) and k > 0
    assert split, "the table did not run over a page: the test no longer tests a break"
