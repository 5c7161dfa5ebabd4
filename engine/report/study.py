"""A validation study's report: the seed paper's Tables 1–3 of the user's own data against
a reference system (:class:`engine.agreement.AgreementStudy`), with Bland–Altman plots, as
HTML (the console's fragment or a whole page), tagged PDF or CSV.

The look is the gait report's (``templates/_report_style.html.j2``); the pages are A4
landscape, as wide as the paper's tables.
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field
from pathlib import Path

from engine import __version__
from engine.agreement import AgreementStudy, StudyRow, bland_altman_png
from engine.errors import InputError
from engine.report.render import _env, _png_uri, day_text
from engine.wording import count

#: (table, caption) in the paper's order
_TABLES = ((1, "Table 1 — view-independent parameters: walking speed and step time"),
           (2, "Table 2 — spatial parameters: stride length, step length and step width"))


@dataclass
class StudyReport:
    """Everything a study's report shows.

    Attributes:
        study: The fitted study.
        title: The report's title.
        system: Heading of the measured system's columns.
        reference: Heading of the reference system's columns (e.g. ``"Vicon"``).
        basis: What was compared, one line each (subjects, trials, sensors, options).
        notes: Trials left out and why, one line each.
    """

    study: AgreementStudy
    title: str = "Agreement with a reference system"
    system: str = "gaitrig"
    reference: str = "reference"
    basis: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def _decimals(row: StudyRow) -> int:
    # seconds to the millisecond (a step-time bias is a few ms), centimetres to 0.01
    return 3 if row.unit == "s" else 2


def _figures(report: StudyReport) -> list[tuple[str, str, str]]:
    """(caption, alt text, data URI) of each parameter's Bland–Altman plot."""
    from engine.agreement import agreement
    from engine.report import plots

    out = []
    units = {r.parameter: r for r in report.study.rows_}
    for parameter, (m, ref) in report.study.pairs_.items():
        row = units.get(parameter)
        if row is None or len(m) < 3:
            continue
        caption = f"Bland–Altman: {parameter} ({count(len(m), 'pair')}, both sides)"
        png = bland_altman_png(m, ref, f"{parameter[0].upper()}{parameter[1:]}: "
                               f"{report.system} − {report.reference}", row.unit, row.scale)
        a = agreement(m * row.scale, ref * row.scale)
        out.append((caption, plots.bland_altman_alt(caption, a.n, a.bias, a.rpc, row.unit),
                    _png_uri(png)))
    return out


def render_study_html(report: StudyReport, *, standalone: bool = True) -> str:
    """The study's report as HTML.

    Args:
        report: What to show.
        standalone: A whole page; False: a fragment for the console.

    Returns:
        The HTML text.
    """
    s = report.study
    tables = [(n, caption, [(r, r.shown(), _decimals(r)) for r in s.rows_ if r.table == n])
              for n, caption in _TABLES]
    notes = [f"{name}: none of its steps matched the reference's in time (within "
             f"{s.max_dt_s:g} s): do both files start together?" for name in s.unmatched_]
    now = _dt.datetime.now(_dt.UTC)
    return _env().get_template("study.html.j2").render(
        r=report, standalone=standalone, version=__version__,
        facts=(f"{count(s.n_subjects_, 'subject')}, {count(s.n_trials_, 'trial')}: "
               f"{report.system} against {report.reference}."),
        tables=[t for t in tables if t[2]], figures=_figures(report),
        notes=[*report.notes, *notes], max_dt=f"{s.max_dt_s:g}",
        generated=f"{day_text(now.date().isoformat())} {now:%H:%M} UTC")


def render_study_pdf(report: StudyReport) -> bytes:
    """The study's report as a tagged PDF/UA-1 document (A4 landscape, WeasyPrint).

    Args:
        report: What to show.

    Returns:
        The PDF bytes.

    Raises:
        RuntimeError: WeasyPrint produced an empty document.
    """
    from weasyprint import HTML
    from weasyprint.urls import URLFetcher

    # as the gait report: only the plots' data: URIs are fetched
    pdf = HTML(string=render_study_html(report),
               url_fetcher=URLFetcher(allowed_protocols={"data"})).write_pdf(
        pdf_variant="pdf/ua-1")
    if not pdf:
        raise RuntimeError("WeasyPrint produced an empty PDF")
    return bytes(pdf)


def save_study_report(report: StudyReport, path: str | Path) -> Path:
    """Write the study's report to ``path``: ``.html``, ``.pdf`` or ``.csv`` (the rows,
    :meth:`engine.agreement.AgreementStudy.csv`), chosen by suffix.

    Args:
        report: What to show.
        path: Destination (overwritten).

    Returns:
        ``path`` as a Path.

    Raises:
        InputError: another suffix.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".pdf":
        path.write_bytes(render_study_pdf(report))
    elif suffix in (".html", ".htm"):
        path.write_text(render_study_html(report), encoding="utf-8")
    elif suffix == ".csv":
        path.write_text(report.study.csv(), encoding="utf-8")
    else:
        raise InputError(f"report path must end in .html, .pdf or .csv, got {path.name!r}")
    return path
