"""The PDF report is a tagged PDF (PDF/UA-1) that a screen reader can read: language,
title, a structure tree in reading order, tables with header cells, every figure with a
text alternative computed from its data, the same as the HTML report's ``alt``.

The PDF's objects are read by :mod:`tests.engine.report.pdf_structure` (no PDF library
is a dependency).
"""

from __future__ import annotations

import html as html_lib
import re
import zlib
from html.parser import HTMLParser

import numpy as np
import pytest

from engine.report import plots
from engine.report.render import ReportData, render_html, render_pdf
from tests.engine.report.pdf_structure import (
    Name,
    PdfObjects,
    StructElem,
    read_objects,
    structure_tree,
)
from tests.engine.report.test_report import _data
from tests.engine.report.test_report_many_sessions import _data as _sessions_data


@pytest.fixture(scope="module")
def single() -> tuple[ReportData, str, PdfObjects, StructElem]:
    data = _data()
    objs = read_objects(render_pdf(data))
    return data, render_html(data), objs, structure_tree(objs)


@pytest.fixture(scope="module")
def progress() -> tuple[ReportData, str, PdfObjects, StructElem]:
    data = _sessions_data(3)
    objs = read_objects(render_pdf(data))
    return data, render_html(data), objs, structure_tree(objs)


def _html_alts(html: str) -> list[str]:
    return [html_lib.unescape(a) for a in re.findall(r'<img src="[^"]+" alt="([^"]*)"', html)]


def test_the_reader_reads_a_structure_tree() -> None:
    """The reader on a hand-made tagged PDF with an object stream (as WeasyPrint writes)."""
    packed = (b"<</Type /StructElem /S /Figure /Alt (Two \\(2\\) feet) /K [0] /P 3 0 R>>"
              b" <</Type /StructElem /S /H1 /K [1] /P 3 0 R>>")
    head = b"4 0 5 " + str(len(packed.split(b" <<")[0]) + 1).encode() + b" "
    stm = zlib.compress(head + packed)
    pdf = (b"%PDF-1.7\n1 0 obj\n<</Type /Catalog /StructTreeRoot 2 0 R /Lang (en)>>\nendobj\n"
           b"2 0 obj\n<</Type /StructTreeRoot /K [3 0 R]>>\nendobj\n"
           b"3 0 obj\n<</Type /StructElem /S /Document /K [5 0 R 4 0 R]>>\nendobj\n"
           b"6 0 obj\n<</Type /ObjStm /N 2 /First " + str(len(head)).encode()
           + b" /Filter /FlateDecode /Length " + str(len(stm)).encode() + b">>\nstream\n"
           + stm + b"\nendstream\nendobj\n"
           b"trailer\n<</Root 1 0 R /Size 7>>\n%%EOF\n")
    objs = read_objects(pdf)
    assert objs.catalog["Lang"] == "en" and isinstance(objs.catalog["Type"], Name)
    tree = structure_tree(objs)
    assert [e.type for e in tree.walk()] == ["StructTreeRoot", "Document", "H1", "Figure"]
    assert tree.find("Figure")[0].alt == "Two (2) feet"


def test_pdf_is_tagged_with_language_title_and_pdf_ua(
        single: tuple[ReportData, str, PdfObjects, StructElem]) -> None:
    data, _, objs, tree = single
    cat = objs.catalog
    assert cat["Lang"] == "en"
    assert objs.get(cat["MarkInfo"])["Marked"] is True
    assert objs.get(cat["ViewerPreferences"])["DisplayDocTitle"] is True
    info = objs.get(objs.trailer["Info"])
    assert info["Title"] == f"{data.title} — {data.subject_code}"
    # PDF/UA-1 identification in the XMP metadata
    raw = objs.streams[cat["Metadata"].num]
    assert re.search(rb"pdfuaid:part[^0-9]{1,3}1", raw), raw[:400]
    assert tree.find("Document") and tree.find("H1")


def test_reading_order_follows_the_report(
        progress: tuple[ReportData, str, PdfObjects, StructElem]) -> None:
    """Headings and figures come in the tree in the order the report reads (the HTML's
    order), across pages; the page footers are not in it."""
    _, html, _, tree = progress
    body = html[html.index("<article"):]
    want = []
    for m in re.finditer(r"<(h1|h2)\b|<img\b|<caption\b", body):
        want.append({"h1": "H1", "h2": "H2", "<img": "Figure",
                     "<caption": "Caption"}.get(m[1] or m[0]))
    got = [e.type for e in tree.walk() if e.type in ("H1", "H2", "Figure")
           or (e.type == "Caption" and _is_table_caption(e, tree))]
    assert got == want
    assert [e.type for e in tree.find("Document")[0].kids][:1] == ["Art"]


def _is_table_caption(e: StructElem, tree: StructElem) -> bool:
    return any(k is e for t in tree.find("Table") for k in t.kids)


def test_every_figure_has_its_computed_alt_text_in_pdf_and_html(
        single: tuple[ReportData, str, PdfObjects, StructElem]) -> None:
    data, html, _, tree = single
    figs = tree.find("Figure")
    alts = [f.alt for f in figs]
    assert len(figs) == 4 and all(alts), alts
    assert alts == _html_alts(html)  # the same words in the console's report
    # computed from the data: the placements of each trial and their extent
    top = alts[0]
    for t in data.trials:
        assert t.placements
        xs = [p["position"][0] for p in t.placements]
        n_l = sum(p["side"] == "L" for p in t.placements)
        n_r = len(t.placements) - n_l
        assert f"{t.name}: {n_l} left and {n_r} right placements along " \
            f"{max(xs) - min(xs):.1f} m" in top
    steps = [s for t in data.trials for s in t.result["steps"]]
    lengths = [100 * s["length_m"] for s in steps if s["side"] == "L"]
    assert f"{len(lengths)} left steps, length {min(lengths):.0f} to {max(lengths):.0f} cm" \
        in alts[2]
    assert alts[1].startswith(f"Ankle height over time in trial {data.trials[0].name}")
    ag = data.agreement[0]  # the figure's row of the agreement table
    assert alts[3] == (f"{data.agreement_figures[0][0]}: differences of {ag.n} paired "
                       f"values against their means; bias {ag.bias:+.2f} {ag.unit}, 95 % "
                       f"limits of agreement bias ± {ag.rpc:.2f} {ag.unit}.")


def test_trend_plot_alt_gives_first_and_last_values(
        progress: tuple[ReportData, str, PdfObjects, StructElem]) -> None:
    data, html, _, tree = progress
    alt = tree.find("Figure")[0].alt
    assert alt is not None and alt == _html_alts(html)[0]
    assert alt.startswith(f"Parameters over 3 sessions, {data.sessions[0].name} to "
                          f"{data.sessions[-1].name}")
    speeds = [sum(s["length_m"] for t in ss.trials for s in t.result["steps"])
              / sum(s["duration_s"] for t in ss.trials for s in t.result["steps"])
              for ss in data.sessions]
    assert f"Walking speed {speeds[0]:.2f} to {speeds[-1]:.2f} m/s" in alt


def test_tables_have_header_cells_that_the_data_cells_point_to(
        progress: tuple[ReportData, str, PdfObjects, StructElem]) -> None:
    _, html, _, tree = progress
    tables = tree.find("Table")
    with_th = [t for t in tables if t.find("TH")]
    # every data table of the HTML (one with <th>) is tagged with its header cells; a
    # table split over pages is one /Table per page
    assert len(with_th) >= len(re.findall(r"<table aria-label", html))
    for t in with_th:
        ids = {th.id for th in t.find("TH")}
        assert None not in ids
        for td in t.find("TD"):
            heads = td.attrs.get("Headers")
            assert heads, "a data cell without header"
            assert set(heads) <= ids
    # the sessions table: a cell is read with its session (row) and parameter (column)
    assert any(len(td.attrs.get("Headers", [])) == 2 for t in with_th for td in t.find("TD"))


class _Cell:
    """One cell of an HTML table: header or data, its scope, text and grid column."""

    def __init__(self, tag: str, attrs: dict[str, str | None]) -> None:
        self.th = tag == "th"
        self.scope = attrs.get("scope")
        self.colspan = int(attrs.get("colspan") or 1)
        self.rowspan = int(attrs.get("rowspan") or 1)
        self.text = ""
        self.col = 0


class _Tables(HTMLParser):
    """The report's tables as rows of cells (with the text a screen reader reads: hidden
    text too), each with its class and whether it has a header row (``<thead>``)."""

    def __init__(self) -> None:
        super().__init__()
        self.tables: list[dict] = []
        self.cell: _Cell | None = None

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        if tag == "table":
            self.tables.append({"cls": a.get("class") or "", "label": a.get("aria-label"),
                                "rows": [], "thead": False})
        elif tag == "thead":
            self.tables[-1]["thead"] = True
        elif tag == "tr":
            self.tables[-1]["rows"].append([])
        elif tag in ("td", "th"):
            self.cell = _Cell(tag, a)
            row = self.tables[-1]["rows"][-1]
            self.cell.col = sum(c.colspan for c in row)
            row.append(self.cell)

    def handle_endtag(self, tag: str) -> None:
        if tag in ("td", "th"):
            self.cell = None

    def handle_data(self, data: str) -> None:
        if self.cell is not None:
            self.cell.text += data


def _check_html_headers(html: str) -> dict[str, int]:
    """Every data cell of every table has a row header (``th scope=row`` in its row, with
    words), and in a table with a header row exactly one column header (``th scope=col``
    over its column); a fact table (no header row) gives a value ONE label. Returns the
    number of data cells per table (by label or class)."""
    p = _Tables()
    p.feed(html[html.index("<article"):])
    counts: dict[str, int] = {}
    for t in p.tables:
        name = t["label"] or t["cls"]
        cols = {}
        for row in t["rows"]:
            for c in row:
                assert c.rowspan == 1, f"{name}: a rowspan header is mis-tagged in the PDF"
                if c.th and c.scope == "col":
                    for k in range(c.colspan):
                        cols[c.col + k] = c
        n = 0
        for row in t["rows"]:
            rowh = [c for c in row if c.th and c.scope == "row"]
            assert all(c.th and c.scope in ("row", "col") for c in row if c.th), name
            for c in (c for c in row if not c.th):
                n += 1
                where = f"{name}: cell {c.text.strip()!r}"
                assert rowh, f"{where} has no row header"
                assert all(h.text.strip() for h in rowh), f"{where}: an empty row header"
                if t["thead"]:
                    heads = {cols[k] for k in range(c.col, c.col + c.colspan) if k in cols}
                    assert len(heads) == 1, f"{where}: {len(heads)} column headers"
                else:
                    assert len(rowh) == 1, f"{where}: read with {len(rowh)} labels"
        counts[name] = counts.get(name, 0) + n
    return counts


def _has_content(e: StructElem) -> bool:
    return any(k.text_ids for k in e.walk())


def _check_pdf_headers(tree: StructElem) -> tuple[int, int]:
    """The same in the PDF structure tree: each /TD's /Headers name the /TH cells of its own
    /TR (row headers, each with content: a hidden repeat is tagged too) and, in a table
    with a /THead, the one /TH of the header rows over the cell's column (WeasyPrint's IDs
    are table-row-column). Returns the numbers of data and fact tables."""
    n_data = n_fact = 0
    for t in tree.find("Table"):
        if not t.find("TH"):
            continue
        head = {th.id for h in t.find("THead") for th in h.find("TH")}
        n_data += bool(head)
        n_fact += not head
        for tr in t.find("TR"):
            if any(k.type == "THead" and tr in k.walk() for k in t.kids):
                continue
            rowh = [k.id for k in tr.kids if k.type == "TH"]
            col = 0
            for k in tr.kids:
                span = int(k.attrs.get("ColSpan", 1))
                if k.type == "TD":
                    heads = list(k.attrs.get("Headers", []))
                    assert rowh and heads[:len(rowh)] == rowh, (heads, rowh)
                    colh = heads[len(rowh):]
                    if head:
                        assert len(colh) == span and set(colh) <= head, (heads, head)
                        assert [int(h.rsplit("-", 1)[1]) for h in colh] == \
                            list(range(col, col + span)), "column header of another column"
                    else:
                        assert not colh and len(rowh) == 1, heads
                else:
                    assert k.type == "TH" and _has_content(k), "an empty row header"
                col += span
    return n_data, n_fact


@pytest.mark.parametrize("report", ["single", "progress"])
def test_every_data_cell_is_read_with_its_row_and_column_header(
        report: str, request: pytest.FixtureRequest) -> None:
    """A number is read with its parameter (and side, comparison, trial, sensor or level)
    and its column; a fact with its label. "single" is a one-session report with an
    agreement section, "progress" a subject report over three sessions."""
    _, html, _, tree = request.getfixturevalue(report)
    counts = _check_html_headers(html)
    want = ({"spatiotemporal parameters", "per trial", "per-sensor quality", "agreement"}
            if report == "single" else
            {"sessions", "changes between sessions", "spatiotemporal parameters",
             "per trial"})
    assert want <= set(counts) and all(counts[k] for k in want), counts
    n_data, n_fact = _check_pdf_headers(tree)
    assert n_data >= len(re.findall(r"<table aria-label", html))
    assert n_fact >= html.count('<table class="meta">') >= 2
    # a left/right row says its parameter too: its header is there, hidden, in both
    assert re.search(r'<tr class="side">\s*<th scope="row" class="l rh"><span class="gr-vh">'
                     r"Step length</span></th>\s*<th[^>]*>left</th>", html)


@pytest.mark.parametrize("n", [1, 4])
def test_placement_alt_counts_per_trial(n: int) -> None:
    rng = np.random.default_rng(n)
    trials = []
    for k in range(n):
        pl = [{"side": "LR"[i % 2], "position": [0.5 + 0.7 * i, 0.05, 0.0]}
              for i in range(5 + k)]
        trials.append((f"t{k}", pl))
        rng.normal()
    alt = plots.foot_placements_alt(trials)
    for k in range(n):
        n_all = 5 + k
        assert f"t{k}: {(n_all + 1) // 2} left and {n_all // 2} right placements along " \
            f"{0.7 * (n_all - 1):.1f} m" in alt
    assert ("one panel each" in alt) == (n > 1)


def test_agreement_figure_alt_is_its_row_both_sides() -> None:
    """Captions and rows as the app writes them (app.server.analysis.agreement_rows)."""
    from engine.report.render import AgreementRow

    data = _data()
    rows = [AgreementRow("Step length", f"single steps {side}", n, 0.9, 1e-4, bias, 2.0,
                         3.0, 0.9, "cm")
            for side, n, bias in (("L", 11, 0.5), ("R", 12, -0.5), ("L+R", 23, 0.1))]
    png = data.agreement_figures[0][1]
    data.agreement = rows
    data.agreement_figures = [("Bland–Altman: step length (single steps, both sides)", png)]
    alt = _html_alts(render_html(data))[-1]
    assert "differences of 23 paired values" in alt and "bias +0.10 cm" in alt
