"""Change over sessions with many sessions (10 and 30): every session is in the report,
nothing runs off the PDF page, the header row repeats on every page the sessions table
spans, and the console's HTML reflows at 320 px (a table scrolls in its own box).

Synthetic sessions (``tests.engine.report.test_report._trial``: 12 steps a trial, two
trials a session) whose steps lengthen by 0.4 cm a session, so the change is known.
"""

from __future__ import annotations

import functools
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from engine.report.plots import MAX_TREND_LABELS, trend_label_indices
from engine.report.progress import SessionTrials
from engine.report.render import ReportData, day_text, latest_changes, render_html, render_pdf
from tests.engine.report.test_report import _trial

needs_poppler = pytest.mark.skipif(shutil.which("pdftoppm") is None,
                                   reason="poppler-utils not installed")
#: A4 at the template's margins (@page: 14mm 12mm 16mm 12mm)
A4_W_MM, RIGHT_MARGIN_MM = 210.0, 12.0


def _sessions(n: int) -> list[SessionTrials]:
    rng = np.random.default_rng(n)
    out = []
    for k in range(n):
        date = f"2026-{1 + k // 28:02d}-{1 + k % 28:02d}"
        trials = [_trial(f"v{k + 1} walk {i + 1}", rng, 0.60 + 0.004 * k, 0.58 + 0.004 * k)
                  for i in range(2)]
        out.append(SessionTrials(f"visit {k + 1}", date, trials))
    return out


def _data(n: int) -> ReportData:
    ss = _sessions(n)
    return ReportData("P-030", [t for s in ss for t in s.trials], sessions=ss)


@functools.cache
def _rendered(n: int) -> tuple[ReportData, str]:
    """The report of ``n`` sessions and its HTML, rendered once for the tests that only
    read them (the HTML, PDF and reflow tests of the same ``n``; ~3-6 s a rendering)."""
    data = _data(n)
    return data, render_html(data)


def _table(html: str, label: str) -> str:
    start = html.index(f'<table aria-label="{label}"')
    return html[start:html.index("</table>", start)]


@pytest.mark.parametrize("n", [10, 30])
def test_html_has_every_session_and_the_latest_changes(n: int) -> None:
    data, html = _rendered(n)
    sessions = _table(html, "sessions")
    rows = re.findall(r'<tr><th scope="row" class="l">([^<]+)</th>', sessions)
    assert rows == [s.name for s in data.sessions]  # all of them, in time order
    # a column per parameter (not per session): the table is as wide for 30 as for 2
    assert sessions.count('<th scope="col"') == 2 + 9
    changes = _table(html, "changes between sessions")
    # the latest session against the first and the previous, once per parameter
    assert f"The latest session, {data.sessions[-1].name}" in changes
    assert changes.count('<th scope="row" class="l rh">first</th>') == 9
    assert changes.count('<th scope="row" class="l rh">previous</th>') == 9
    step_l = re.search(r"Step length, left</th><th scope=\"row\" class=\"l rh\">first</th>\s*"
                       r"<td class=\"l\">longer by ([0-9.]+) cm", changes)
    assert step_l and float(step_l[1]) == pytest.approx(0.4 * (n - 1), abs=1.0)
    # the trend plot's alt text covers the whole series
    alt = re.search(r'<img src="data:image/png;base64,[^"]+" alt="(Parameters over [^"]+)"',
                    html)
    assert alt and f"over {n} sessions, {data.sessions[0].name} to " \
        f"{data.sessions[-1].name}" in alt[1]
    assert "every session is a point" in html


def test_latest_changes_of_two_sessions_has_no_previous() -> None:
    data = _data(2)
    from engine.report.progress import session_progress

    latest = latest_changes(session_progress(data.sessions))
    assert all([c.ref for c in changes] == [0] for _, changes in latest)
    assert all(c.to == 1 for _, changes in latest for c in changes)
    assert "against the previous" not in render_html(data)


def test_trend_labels_are_thinned_but_keep_first_and_last() -> None:
    assert trend_label_indices(4) == [0, 1, 2, 3]
    for n in (7, 10, 30, 100):
        idx = trend_label_indices(n)
        assert idx[0] == 0 and idx[-1] == n - 1 and len(idx) == MAX_TREND_LABELS
        assert np.ptp(np.diff(idx)) <= 1  # evenly spaced


def _layout_overflow(html: str) -> tuple[list[str], list[list[str]]]:
    """Boxes that reach past the page's right margin, from WeasyPrint's layout, and the
    header cells of the sessions table on each page it is on."""
    from weasyprint import HTML
    from weasyprint.formatting_structure import boxes

    doc = HTML(string=html).render()
    over: list[str] = []
    heads: list[list[str]] = []
    for k, page in enumerate(doc.pages):
        pb = page._page_box
        right = pb.margin_width() - pb.margin_right  # CSS px

        def walk(box: Any, k: int = k, right: float = right) -> None:
            if isinstance(box, boxes.MarginBox):
                return
            if box.width is not None and box.position_x is not None:
                edge = box.position_x + box.margin_width() - box.margin_right
                if edge > right + 0.5:
                    tag = getattr(box, "element_tag", "?")
                    over.append(f"page {k + 1}: {type(box).__name__} <{tag}> ends at "
                                f"{edge:.1f} px, margin at {right:.1f} px")
            for child in getattr(box, "children", []):
                walk(child)

        walk(pb)

        def find(box: Any) -> None:
            el = getattr(box, "element", None)
            if (isinstance(box, boxes.TableBox) and el is not None
                    and el.get("aria-label") == "sessions"):
                heads.append(["".join(c.element.itertext()) for g in box.children
                              if g.is_header for r in g.children for c in r.children])
                return
            for child in getattr(box, "children", []):
                find(child)

        find(pb)
    return over, heads


@needs_poppler
def test_pdf_keeps_every_session_inside_the_page(tmp_path: Path, artifacts_dir: Path) -> None:
    # 30 sessions: the table spans pages (10 fitted on one and checked nothing more, at
    # 15 s of the suite's time)
    n = 30
    data, html = _rendered(n)
    # WeasyPrint's own layout: no box past the right margin; the header row on every
    # page the sessions table spans
    over, heads = _layout_overflow(html)
    assert not over, over[:5]
    assert len(heads) >= 2
    assert all(h and h[0] == "Session" and "Walking speed (m/s)" in h for h in heads), heads
    pdf = tmp_path / "r.pdf"
    pdf.write_bytes(render_pdf(data))
    text = subprocess.run(["pdftotext", "-layout", str(pdf), "-"], capture_output=True,
                          text=True, check=True, timeout=120).stdout
    sessions_text = text[text.index("Change over sessions"):text.index("The latest session")]
    flat = re.sub(r"\s+", " ", sessions_text)
    for s in data.sessions:  # the name wraps in its cell ("1 Jan" over "2026 visit 1")
        words = [*day_text(s.date).split(), s.label]
        assert re.search(r"\b" + r"\b.*?\b".join(map(re.escape, words)) + r"\b", flat), s.name
    # (days as the report writes them, "1 Jan 2026")
    assert len(re.findall(r"\b\d{1,2} (?:Jan|Feb)\b", flat)) >= n
    # and as drawn: the strip right of the right margin is blank on every page
    subprocess.run(["pdftoppm", "-r", "50", "-png", str(pdf), str(tmp_path / "p")],
                   check=True, timeout=120)
    pages = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted(tmp_path.glob("p-*.png"))]
    assert pages
    for k, img in enumerate(pages):
        px_per_mm = img.shape[1] / A4_W_MM
        strip = img[:, round((A4_W_MM - RIGHT_MARGIN_MM + 1.0) * px_per_mm):]
        assert strip.min() > 245, f"page {k + 1}: ink right of the margin"
    shutil.copy(pdf, artifacts_dir / f"report_{n}_sessions.pdf")
    cv2.imwrite(str(artifacts_dir / f"report_{n}_sessions_p1.png"), pages[0])


REFLOW_WIDTH = 320  # CSS px: a 1280 px window at 400 % (WCAG 1.4.10)


@pytest.mark.browser
def test_html_reflows_at_320_px(browser: Any, artifacts_dir: Path) -> None:
    """The saved HTML report of 30 sessions at 320 px: the page does not scroll sideways;
    each table that is wider scrolls in its own box, a named region that takes the focus."""
    ctx = browser.new_context(viewport={"width": REFLOW_WIDTH, "height": 700})
    page = ctx.new_page()
    page.set_content(_rendered(30)[1])
    scroll, inner = page.evaluate("[document.documentElement.scrollWidth, window.innerWidth]")
    assert scroll <= inner + 1, f"the page scrolls sideways: {scroll} > {inner}"
    boxes = page.evaluate("""() => [...document.querySelectorAll('table')].map((t) => {
        const b = t.closest('.gr-scroll');
        return {label: t.getAttribute('aria-label') || t.className,
                scrolls: b ? b.scrollWidth > b.clientWidth + 1 : null,
                reachable: b ? b.tabIndex === 0 && b.getAttribute('role') === 'region'
                               && !!b.getAttribute('aria-label') : null,
                right: t.getBoundingClientRect().right}; })""")
    by = {b["label"]: b for b in boxes}
    assert by["sessions"]["scrolls"] and by["sessions"]["reachable"], by["sessions"]
    for b in boxes:
        # a table either fits or scrolls in a reachable box of its own
        assert b["right"] <= inner + 1 or (b["scrolls"] and b["reachable"]), b
    page.screenshot(path=str(artifacts_dir / "report_30_sessions_320px.png"), full_page=False)
    ctx.close()


def test_a_parameter_missing_in_the_latest_session_says_so() -> None:
    data = _data(4)
    for t in data.sessions[-1].trials:
        for s in t.result["steps"]:
            s["width_m"] = None
    html = render_html(data)
    changes = _table(html, "changes between sessions")
    row = re.search(r"Step width</th><th scope=\"row\"[^>]*>–</th><td class=\"l\" colspan=\"3\">"
                    r"not measured in the latest session", changes)
    assert row, changes
    # its values of the other sessions are still in the sessions table, the latest a dash
    sessions = _table(html, "sessions")
    last_row = sessions[sessions.index(data.sessions[-1].name):]
    assert "<td>–</td>" in last_row
