"""``gaitrig gait FILE``: spatiotemporal gait parameters of a C3D, TRC or skeleton CSV file.

With ``--json`` one JSON object is printed (schema: ``docs/gait-json.md``); otherwise a
human-readable summary and step table. Errors: one line on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any, Literal

from app.commands._file_options import (
    add_ankle_arguments,
    add_marker_arguments,
    add_units_argument,
    add_up_argument,
    ankle_width_m,
    up_axis_missing,
)

HELP = "gait parameters (steps, strides, speed, cadence ...) of a C3D/TRC/CSV file"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's options."""
    parser.add_argument("file", metavar="FILE", help="a .c3d, .trc or skeleton .csv file")
    add_marker_arguments(parser, "left-foot marker to analyse (default: automatic, e.g. "
                                 "LANK/LHEE)", "right-foot marker to analyse")
    add_up_argument(parser, "vertical axis of the file, '-y' for Y down (default: detected)")
    add_units_argument(parser, "length unit of the file's numbers (default: from the file)")
    add_ankle_arguments(parser)
    parser.add_argument("--method", choices=["crossing", "heelstrike"], default="crossing",
                        help="crossing: foot placements where the ankles pass each other "
                             "(seed paper); heelstrike: Zeni foot strike / foot off")
    parser.add_argument("--exclude-first", choices=["auto", "yes", "no", "L", "R"],
                        default="auto",
                        help="drop the first step and stride of each pass (acceleration); "
                             "auto: only for passes that start from standing; L/R: the "
                             "subject started with this foot, drop its first step and the "
                             "other foot's first stride (seed paper's literal rule)")
    parser.add_argument("--max-crossing-gap", type=float, default=0.5, metavar="S",
                        help="crossing method: find a crossing hidden in a gap of one ankle "
                             "up to S seconds long (a far ankle seen from one side; "
                             "default 0.5; 0: only between consecutive samples, as the "
                             "seed paper)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def _fmt(v: float | None, scale: float = 1.0, nd: int = 1) -> str:
    return "—" if v is None else f"{v * scale:.{nd}f}"


def _table(doc: dict[str, Any]) -> str:
    s = doc["summary"]
    lines = [f"method: {s['method']}   passes: {s['n_passes']}   steps: {s['n_steps']}   "
             f"strides: {s['n_strides']}",
             f"walking speed: {_fmt(s['walking_speed_m_s'], 1, 2)} m/s   "
             f"cadence: {_fmt(s['cadence_steps_min'])} steps/min"]
    # which point of each foot was measured (a lateral ankle marker's joint centre ...)
    for side, word in (("L", "left"), ("R", "right")):
        point = (s.get("foot_points") or {}).get(side)
        if point:
            lines.append(f"{word} foot measured at: {point}")
    lines += [f"note: {n}" for n in s.get("notes") or []]
    lines += ["", f"{'parameter':<18}{'mean':>8}{'SD':>8}{'CV %':>8}{'left':>8}"
                  f"{'right':>8}{'asym %':>8}"]
    for key, label, scale in (("step_length_m", "step length cm", 100.0),
                              ("step_width_m", "step width cm", 100.0),
                              ("step_time_s", "step time s", 1.0),
                              ("stride_length_m", "stride length cm", 100.0),
                              ("stride_time_s", "stride time s", 1.0)):
        p = s[key]
        nd = 1 if scale == 100.0 else 3
        lines.append(f"{label:<18}{_fmt(p['mean'], scale, nd):>8}{_fmt(p['sd'], scale, nd):>8}"
                     f"{_fmt(p['cv_pct']):>8}{_fmt(p['left_mean'], scale, nd):>8}"
                     f"{_fmt(p['right_mean'], scale, nd):>8}{_fmt(p['asymmetry_pct']):>8}")
    for key, label in (("stance_pct", "stance %"), ("swing_pct", "swing %"),
                       ("double_support_pct", "double support %")):
        p = s[key]
        if p is not None:
            lines.append(f"{label:<18}{_fmt(p.get('mean')):>8}{'':>16}"
                         f"{_fmt(p.get('left_mean')):>8}{_fmt(p.get('right_mean')):>8}")
    # "at s": the instant the step ends; "duration s": the step time (the summary's)
    lines += ["", f"{'step':>4} {'side':>4} {'at s':>8} {'length cm':>10} {'width cm':>9} "
                  f"{'duration s':>10}"]
    for i, st in enumerate(doc["steps"], 1):
        lines.append(f"{i:>4} {st['side']:>4} {st['time_s']:>8.3f} {st['length_m'] * 100:>10.1f} "
                     f"{st['width_m'] * 100:>9.1f} {st['duration_s']:>10.3f}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Analyse the file; print JSON or a table. Returns the exit code."""
    import json

    from engine.errors import GaitrigError
    from engine.gait import GaitAnalysis
    from engine.mocap import load_feet

    missing = up_axis_missing("gait", args)
    if missing:
        print(missing, file=sys.stderr)
        return 2
    if not 0.0 <= args.max_crossing_gap <= 1.0:
        print("gaitrig gait: error: --max-crossing-gap must be between 0 and 1 s (a longer "
              f"gap can hide a whole step), got {args.max_crossing_gap:g}", file=sys.stderr)
        return 2
    excl: bool | Literal["auto", "L", "R"] = (
        args.exclude_first if args.exclude_first in ("auto", "L", "R")
        else args.exclude_first == "yes")
    try:
        feet = load_feet(args.file, left=args.left, right=args.right, up=args.up,
                         units=args.units, ankle_markers=args.ankle_markers,
                         ankle_width_m=ankle_width_m(args))
        ga = GaitAnalysis(args.method, exclude_first=excl,
                          max_crossing_gap_s=args.max_crossing_gap).fit(feet)
    except GaitrigError as exc:
        print(f"gaitrig gait: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"gaitrig gait: error: cannot read {args.file}: {exc.strerror or exc}",
              file=sys.stderr)
        return 2
    doc = ga.to_dict()
    if args.json:
        print(json.dumps(doc))
    else:
        print(_table(doc))
    return 0
