"""``gaitrig agreement``: a validation study of a system's files against a reference's.

Each trial is one walk recorded by both systems: the measured file (a gaitrig export or
another system's C3D/TRC/skeleton CSV) and the reference's (Vicon C3D ...), given as
``--pair SUBJECT MEASURED REFERENCE`` (repeated) or as the rows of ``--manifest
FILE.csv`` (header ``subject,measured,reference[,offset_s]``, paths relative to the
manifest's folder). Both files of a trial are analysed as ``gaitrig gait`` analyses one
(``app.server.analysis.analyse_file``, the same method for both), the reference's steps
put on the measured file's time axis (``offset_s`` added to their times, the server's
reference ``offset_s``), and :class:`engine.agreement.AgreementStudy` computes seed 000's
Tables 1–3. Output: a text table, ``--json``, or ``-o`` a CSV, HTML or PDF report.

A trial file that cannot be analysed is named with the engine's reason and left out; the
exit code is 0 when any row was computed, 1 when none could be, 2 for bad input (a
missing file, an unreadable manifest, a bad option).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from app.commands._file_options import (
    add_ankle_arguments,
    add_marker_arguments,
    add_units_argument,
    add_up_argument,
    ankle_width_m,
    up_axis_missing,
)
from engine.wording import count

if TYPE_CHECKING:
    from engine.agreement import AgreementStudy, StudyTrial

HELP = ("agreement of a system's walks with a reference system's (seed paper's Tables 1-3: "
        "bias, RPC, ICC ...) from pairs of C3D/TRC/CSV files")

_OUTPUTS = (".csv", ".html", ".htm", ".pdf")


class UsageError(Exception):
    """Bad input to the command: its message is printed after ``gaitrig agreement:
    error:`` and the exit code is 2."""


@dataclass(frozen=True)
class Pair:
    """One trial: the measured and reference files of one walk of a subject."""

    subject: str
    measured: Path
    reference: Path
    offset_s: float  # added to the reference's step and stride times


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's options."""
    src = parser.add_mutually_exclusive_group(required=True)
    src.add_argument("--pair", nargs=3, action="append", metavar=("SUBJECT", "MEASURED",
                                                                  "REFERENCE"),
                     help="one walk: the subject's code, the system's file of it and the "
                          "reference's (.c3d, .trc or skeleton .csv); repeat for each walk")
    src.add_argument("--manifest", type=Path, metavar="FILE.csv",
                     help="CSV with the header subject,measured,reference[,offset_s], one "
                          "walk a row; paths relative to the manifest's folder")
    parser.add_argument("--offset-s", type=float, default=0.0, metavar="S",
                        help="seconds added to the reference's times to put them on the "
                             "measured file's time axis (the measured file's time of the "
                             "reference's start, as the server's reference offset_s; "
                             "default 0: both started together); a manifest's offset_s "
                             "column overrides it per walk")
    parser.add_argument("--method", choices=["crossing", "heelstrike"], default="crossing",
                        help="crossing: foot placements where the ankles pass each other "
                             "(seed paper); heelstrike: Zeni foot strike / foot off; the "
                             "same for both systems")
    parser.add_argument("--max-dt", type=float, default=0.25, metavar="S",
                        help="largest time difference of a measured and a reference step "
                             "of the same side taken as the same step (default 0.25 s)")
    add_marker_arguments(parser, "the reference files' left-foot marker (default: automatic)",
                         "the reference files' right-foot marker")
    add_up_argument(parser, "vertical axis of the reference files, '-y' for Y down (default: "
                            "detected)")
    add_units_argument(parser, "length unit of the reference files' numbers (default: from "
                               "each file)")
    add_ankle_arguments(parser)
    parser.add_argument("--system", default="gaitrig", metavar="NAME",
                        help="the measured system's name in the table headings (default "
                             "gaitrig)")
    parser.add_argument("--reference-name", default="reference", metavar="NAME",
                        help="the reference system's name in the table headings, e.g. "
                             "Vicon (default reference)")
    parser.add_argument("--title", default="Agreement with a reference system",
                        help="title of the HTML/PDF report")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("-o", "--output", type=Path, metavar="PATH",
                        help="write the study: .csv (the table rows), .html or .pdf (report)")
    parser.epilog = ("--left/--right, --up, --units, --ankle-markers and --ankle-width-mm "
                     "apply to the reference files only; the measured files are read as "
                     "detected (check one with gaitrig gait FILE).")


def _manifest_pairs(path: Path, default_offset_s: float) -> list[Pair]:
    """The manifest's walks.

    Raises:
        UsageError: the file cannot be read, lacks a column, or a row is incomplete
            (its line named).
    """
    try:
        text = path.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise UsageError(f"cannot read the manifest {path}: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise UsageError(f"the manifest {path} is not a text (UTF-8) CSV file") from exc
    reader = csv.DictReader(text.splitlines())
    header = [(h or "").strip().lower() for h in reader.fieldnames or []]
    missing = [c for c in ("subject", "measured", "reference") if c not in header]
    if missing:
        raise UsageError(f"the manifest {path.name} has no {', '.join(missing)} column: its "
                         "first line must be the header subject,measured,reference"
                         "[,offset_s]" + (f" (it is {','.join(header)})" if header else ""))
    reader.fieldnames = header
    folder = path.parent
    pairs = []
    try:
        for row in reader:
            line = reader.line_num
            cells = {k: (v or "").strip() for k, v in row.items() if isinstance(k, str)}
            if not any(cells.values()):
                continue
            empty = [c for c in ("subject", "measured", "reference") if not cells.get(c)]
            if empty:
                raise UsageError(f"{path.name} line {line}: no {' or '.join(empty)} given")
            off = default_offset_s
            if cells.get("offset_s"):
                try:
                    off = float(cells["offset_s"])
                except ValueError:
                    raise UsageError(f"{path.name} line {line}: offset_s "
                                     f"{cells['offset_s']!r} is not a number of seconds"
                                     ) from None
                if not math.isfinite(off):
                    raise UsageError(f"{path.name} line {line}: offset_s must be finite")
            pairs.append(Pair(cells["subject"], folder / cells["measured"],
                              folder / cells["reference"], off))
    except csv.Error as exc:
        raise UsageError(f"{path.name} line {reader.line_num}: not readable as CSV: "
                         f"{exc}") from exc
    if not pairs:
        raise UsageError(f"the manifest {path.name} lists no walk: give one line "
                         "subject,measured,reference a walk under its header")
    return pairs


def _pairs(args: argparse.Namespace) -> list[Pair]:
    """The walks given, each file checked to exist.

    Raises:
        UsageError: bad manifest, no walk, or files that do not exist (all named).
    """
    if args.manifest is not None:
        pairs = _manifest_pairs(args.manifest, args.offset_s)
    else:
        pairs = [Pair(s.strip(), Path(m), Path(r), args.offset_s) for s, m, r in args.pair]
        if any(not p.subject for p in pairs):
            raise UsageError("--pair needs a subject code before its two files")
    missing = list(dict.fromkeys(str(f) for p in pairs for f in (p.measured, p.reference)
                                 if not f.is_file()))
    if missing:
        raise UsageError(f"no such file: {', '.join(missing)}")
    return pairs


def _failure(exc: BaseException, path: Path, reference: bool) -> str:
    """Why ``path`` gave no steps, in the CLI's words. A measured file is read without
    the file options (they are the reference's): their advice is not given for it."""
    from engine.errors import GaitrigError, cli_say

    if not reference and isinstance(exc, GaitrigError) and exc.structured:
        reason = exc.words(cli_say, advice=False)
        return (f"{reason} (the file options here apply to the reference files: check "
                f"this file with gaitrig gait {path.name} and its options)")
    return str(exc)


def _trials(pairs: list[Pair], args: argparse.Namespace
            ) -> tuple[dict[str, list[StudyTrial]], list[dict[str, str]]]:
    """Analyse every file (each once) and make the study's trials.

    Returns:
        subject → trials, and ``{"file", "error"}`` for each file that failed (its walk
        left out).
    """
    from app.server.analysis import analyse_file, study_trial
    from engine.errors import GaitrigError

    done: dict[tuple[bool, Path], dict[str, Any] | str] = {}
    failed: list[dict[str, str]] = []

    def gait(path: Path, reference: bool) -> dict[str, Any] | None:
        key = (reference, path.resolve())
        if key not in done:
            try:
                if reference:
                    a = analyse_file(path, args.method, args.left, args.right, args.up,
                                     args.units, args.ankle_markers, ankle_width_m(args))
                else:
                    a = analyse_file(path, args.method)
                done[key] = a["gait"]
            except GaitrigError as exc:
                done[key] = _failure(exc, path, reference)
                failed.append({"file": str(path), "error": str(done[key])})
        got = done[key]
        return got if isinstance(got, dict) else None

    trials: dict[str, list[StudyTrial]] = {}
    for p in pairs:
        m, r = gait(p.measured, False), gait(p.reference, True)
        if m is None or r is None:
            continue
        trials.setdefault(p.subject, []).append(study_trial(
            m, r, p.offset_s, name=f"{p.subject}: {p.measured.name} vs {p.reference.name}"))
    return trials, failed


def _num(v: float, nd: int) -> str:
    # + 0.0: a bias of -0.00004 cm is "0.0", not "-0.0"
    return "—" if not math.isfinite(v) else f"{round(v, nd) + 0.0:.{nd}f}"


def _p(v: float) -> str:
    return "—" if not math.isfinite(v) else "<0.001" if v < 0.001 else f"{v:.3f}"


def _table(study: AgreementStudy, system: str, reference: str) -> str:
    """The study's rows in the paper's layout, one table after the other."""
    head = (f"{'parameter':<28}{system[:16]:>17}{reference[:16]:>17}{'r':>7}{'p':>8}{'N':>5}"
            f"{'bias':>8}{'RPC':>8}{'CV %':>7}{'ICC(A,1)':>9}")
    sub = f"{'':<28}{'mean ± SD':>17}{'mean ± SD':>17}"
    lines: list[str] = []
    titles = {1: "Table 1: view-independent parameters",
              2: "Table 2: spatial parameters"}
    table = None
    for row in study.rows_:
        if row.table != table:
            table = row.table
            if lines:
                lines.append("")
            lines += [titles.get(table, f"Table {table}"), head, sub]
        a = row.shown()
        nd = 3 if row.unit == "s" else 1
        lines.append(f"{row.label:<28}"
                     f"{_num(a.mean_measured, nd) + ' ± ' + _num(a.sd_measured, nd):>17}"
                     f"{_num(a.mean_reference, nd) + ' ± ' + _num(a.sd_reference, nd):>17}"
                     f"{_num(a.r, 2):>7}{_p(a.p):>8}{a.n:>5}{_num(a.bias, nd):>8}"
                     f"{_num(a.rpc, nd):>8}{_num(a.cv_pct, 1):>7}{_num(a.icc_a1, 2):>9}")
    return "\n".join(lines)


def _finite(d: dict[str, Any]) -> dict[str, Any]:
    """NaN (a statistic that does not exist, e.g. r of constant values) as JSON null."""
    return {k: None if isinstance(v, float) and not math.isfinite(v) else v
            for k, v in d.items()}


def _notes(study: AgreementStudy | None, failed: list[dict[str, str]]) -> list[str]:
    """One sentence per file that failed and per walk none of whose steps matched."""
    notes = [f"{Path(f['file']).name} was left out: {f['error']}" for f in failed]
    if study is not None:
        notes += [f"{name}: no step matched the reference in time (within "
                  f"{study.max_dt_s:g} s): are both files on one time axis (offset_s)?"
                  for name in study.unmatched_]
    return notes


def _write(study: AgreementStudy, out: Path, args: argparse.Namespace,
           pairs: list[Pair], notes: list[str]) -> None:
    """Write ``study`` to ``out``: its CSV, or the study report (HTML/PDF)."""
    from engine.report.study import StudyReport, save_study_report

    offsets = sorted({p.offset_s for p in pairs})
    walks: dict[str, int] = {}
    for p in pairs:
        walks[p.subject] = walks.get(p.subject, 0) + 1
    basis = ["Subjects: " + ", ".join(f"{k} ({count(n, 'trial')})" for k, n in walks.items())
             + " given.",
             f"Steps found by the {args.method} method in both systems' files.",
             f"Single steps and strides of one side matched within {study.max_dt_s:g} s.",
             "Reference times shifted by " + (
                 f"{offsets[0]:g} s" if len(offsets) == 1 else
                 f"{offsets[0]:g} to {offsets[-1]:g} s (per trial)")
             + " to the measured files' time axis."]
    save_study_report(StudyReport(study, title=args.title, system=args.system,
                                  reference=args.reference_name, basis=basis, notes=notes),
                      out)


def run(args: argparse.Namespace) -> int:
    """Analyse every walk's two files, fit the study and print or write it. Returns the
    exit code."""
    import json

    from engine.agreement import AgreementStudy
    from engine.errors import GaitrigError, InsufficientDataError

    def refuse(message: str) -> int:
        print(f"gaitrig agreement: error: {message}", file=sys.stderr)
        return 2

    missing = up_axis_missing("agreement", args)
    if missing:
        print(missing, file=sys.stderr)
        return 2
    if not (math.isfinite(args.max_dt) and 0.0 < args.max_dt <= 1.0):
        return refuse(f"--max-dt must be more than 0 and at most 1 s (a longer one pairs "
                      f"neighbouring steps), got {args.max_dt:g}")
    if not math.isfinite(args.offset_s):
        return refuse("--offset-s must be a number of seconds")
    out: Path | None = args.output
    if out is not None:
        if out.suffix.lower() not in _OUTPUTS:
            return refuse(f"-o must end in .csv, .html or .pdf, got {out.name!r}")
        if not out.parent.is_dir():
            return refuse(f"folder {out.parent} does not exist")
    try:
        pairs = _pairs(args)
    except UsageError as exc:
        return refuse(str(exc))
    trials, failed = _trials(pairs, args)
    study: AgreementStudy | None = None
    error = None
    try:
        study = AgreementStudy(max_dt_s=args.max_dt).fit(trials)
    except InsufficientDataError as exc:
        error = str(exc)
    notes = _notes(study, failed)
    if args.json:
        print(json.dumps({
            "subjects": 0 if study is None else study.n_subjects_,
            "trials": 0 if study is None else study.n_trials_,
            "rows": [] if study is None else [_finite(r.to_dict()) for r in study.rows_],
            "unmatched": [] if study is None else study.unmatched_,
            "failed": failed}))
    if study is None:
        for n in notes:
            print(f"gaitrig agreement: {n}", file=sys.stderr)
        print(f"gaitrig agreement: error: {error}", file=sys.stderr)
        return 1
    if out is not None:
        try:
            _write(study, out, args, pairs, notes)
        except GaitrigError as exc:
            return refuse(str(exc))
        except OSError as exc:
            return refuse(f"cannot write {out}: {exc.strerror or exc}")
    if not args.json:
        if out is None:
            print(f"{args.system} vs {args.reference_name}: "
                  f"{count(study.n_subjects_, 'subject')}, {count(study.n_trials_, 'trial')} "
                  f"({args.method} method; steps matched within {study.max_dt_s:g} s)")
            print()
            print(_table(study, args.system, args.reference_name))
        else:
            print(f"gaitrig agreement: {out} ({count(study.n_subjects_, 'subject')}, "
                  f"{count(study.n_trials_, 'trial')}, {count(len(study.rows_), 'row')})")
        if notes:
            print()
            for n in notes:
                print(f"note: {n}")
    return 0
