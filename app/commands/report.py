"""``gaitrig report FILE... --subject CODE -o report.pdf``: a gait report from files.

Each FILE (C3D, TRC or skeleton CSV) is one walking trial; the report (the same template
as the console's) pools their steps. The output type follows the suffix of ``-o``
(``.pdf`` or ``.html``). Errors: one line on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from app.commands._file_options import (
    add_ankle_arguments,
    add_marker_arguments,
    add_units_argument,
    add_up_argument,
    ankle_width_m,
    up_axis_missing,
)
from engine.wording import count

HELP = "gait report (HTML or PDF) of one or more C3D/TRC/CSV walking trials"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's options."""
    parser.add_argument("files", metavar="FILE", nargs="+",
                        help="walking trials: .c3d, .trc or skeleton .csv files")
    parser.add_argument("--subject", required=True, metavar="CODE",
                        help="subject code printed on the report (pseudonym, not a name)")
    parser.add_argument("--method", choices=["crossing", "heelstrike"], default="crossing",
                        help="crossing: foot placements where the ankles pass each other "
                             "(seed paper); heelstrike: Zeni foot strike / foot off")
    add_marker_arguments(parser, "left-foot marker (default: automatic)", "right-foot marker")
    add_up_argument(parser, "vertical axis of the files, '-y' for Y down (default: detected)")
    add_units_argument(parser, "length unit of the files' numbers (default: from each file)")
    add_ankle_arguments(parser)
    parser.add_argument("--title", default="Gait report", help="report title")
    parser.add_argument("-o", "--output", required=True, type=Path, metavar="PATH",
                        help="report file: .pdf or .html")


def run(args: argparse.Namespace) -> int:
    """Analyse every file and write the report. Returns the exit code."""
    from app.server.analysis import analyse_file, build_report
    from engine.errors import GaitrigError
    from engine.report.render import save_report

    missing = up_axis_missing("report", args)
    if missing:
        print(missing, file=sys.stderr)
        return 2
    out: Path = args.output
    if out.suffix.lower() not in (".pdf", ".html", ".htm"):
        print(f"gaitrig report: error: -o must end in .pdf or .html, got {out.name!r}",
              file=sys.stderr)
        return 2
    if not out.parent.is_dir():
        print(f"gaitrig report: error: folder {out.parent} does not exist", file=sys.stderr)
        return 2
    analyses = []
    for f in args.files:
        p = Path(f)
        if not p.is_file():
            print(f"gaitrig report: error: {f}: no such file", file=sys.stderr)
            return 2
        try:
            analyses.append(analyse_file(p, args.method, args.left, args.right, args.up,
                                         args.units, args.ankle_markers, ankle_width_m(args)))
        except GaitrigError as exc:
            print(f"gaitrig report: error: {p.name}: {exc}", file=sys.stderr)
            return 2
    try:
        data = build_report(args.subject, analyses, title=args.title)
        save_report(data, out)
    except GaitrigError as exc:
        print(f"gaitrig report: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"gaitrig report: error: cannot write {out}: {exc.strerror or exc}",
              file=sys.stderr)
        return 2
    n = sum(len(a["gait"]["steps"]) for a in analyses)
    print(f"gaitrig report: {out} ({count(len(analyses), 'trial')}, {count(n, 'step')})")
    return 0
