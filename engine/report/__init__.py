"""The per-subject gait report (HTML and tagged PDF) and its building blocks.

* :mod:`engine.report.render` — :class:`ReportData` / :class:`TrialData` in,
  :func:`save_report` (``.html`` or ``.pdf``), :func:`render_html`, :func:`render_pdf` out.
* :mod:`engine.report.normative` — normative ranges (with their sources) and published
  minimal detectable changes, loadable from a lab's own JSON.
* :mod:`engine.report.progress` — change of a subject's gait over sessions
  (:func:`session_progress`).
* :mod:`engine.report.study` — a validation study's report (:class:`StudyReport`:
  Tables 1–3 of :class:`engine.agreement.AgreementStudy`, Bland–Altman plots),
  :func:`save_study_report` (``.html``, ``.pdf`` or ``.csv``).
* :mod:`engine.report.plots` — the figures (matplotlib, PNG bytes) and their text
  alternatives.

The names of ``__all__`` import from this package (``from engine.report import
save_report``); each is loaded from its module on first use.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from engine import _lazy_exports

#: public name → the module that defines it
_EXPORTS: dict[str, str] = {
    "ReportData": "engine.report.render",
    "TrialData": "engine.report.render",
    "QualityInfo": "engine.report.render",
    "AgreementRow": "engine.report.render",
    "save_report": "engine.report.render",
    "render_html": "engine.report.render",
    "render_pdf": "engine.report.render",
    "NormativeRange": "engine.report.normative",
    "MdcValue": "engine.report.normative",
    "load_normative_ranges": "engine.report.normative",
    "save_normative_ranges": "engine.report.normative",
    "SessionTrials": "engine.report.progress",
    "Progress": "engine.report.progress",
    "session_progress": "engine.report.progress",
    "load_mdc_values": "engine.report.progress",
    "save_mdc_values": "engine.report.progress",
    "StudyReport": "engine.report.study",
    "render_study_html": "engine.report.study",
    "render_study_pdf": "engine.report.study",
    "save_study_report": "engine.report.study",
}

__all__ = [
    "AgreementRow",
    "MdcValue",
    "NormativeRange",
    "Progress",
    "QualityInfo",
    "ReportData",
    "SessionTrials",
    "StudyReport",
    "TrialData",
    "load_mdc_values",
    "load_normative_ranges",
    "render_html",
    "render_pdf",
    "render_study_html",
    "render_study_pdf",
    "save_mdc_values",
    "save_normative_ranges",
    "save_report",
    "save_study_report",
    "session_progress",
]

if TYPE_CHECKING:  # what type checkers see; at run time __getattr__ loads them
    from engine.report.normative import (
        MdcValue,
        NormativeRange,
        load_normative_ranges,
        save_normative_ranges,
    )
    from engine.report.progress import (
        Progress,
        SessionTrials,
        load_mdc_values,
        save_mdc_values,
        session_progress,
    )
    from engine.report.render import (
        AgreementRow,
        QualityInfo,
        ReportData,
        TrialData,
        render_html,
        render_pdf,
        save_report,
    )
    from engine.report.study import (
        StudyReport,
        render_study_html,
        render_study_pdf,
        save_study_report,
    )

__getattr__, __dir__ = _lazy_exports(__name__, _EXPORTS, globals())
