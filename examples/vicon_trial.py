"""Gait parameters of a mocap trial from Python, and their event timing against the
events annotated in the file (e.g. by Vicon Nexus).

Run from the repository folder (defaults to the real Vicon trial of ``../shared/data``)::

    .venv/bin/python examples/vicon_trial.py [TRIAL.c3d|.trc|.csv] [--out FOLDER]

What it shows, in the order a research engineer needs it:

1. ``load_feet``: what was found in the file (marker names, unit, up axis, pelvis,
   annotated events) — check this before trusting any number;
2. ``GaitAnalysis(...).fit``: the summary and per-step tables (``to_records``), written as
   CSV (one row per step; SI units in the column names);
3. ``match_events``: each detected foot strike / foot off against the file's own
   annotated event of the same side and kind (detected − annotated, ms).

Everything is on the file's time axis and in metres, Z up.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

from engine import GaitAnalysis, GaitrigError, load_feet, match_events

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_TRIAL = ROOT.parent / "shared" / "data" / "mocap" / "kineticstoolkit" / "walk.c3d"


def write_csv(path: Path, rows: list[dict[str, object]]) -> None:
    """Rows of ``GaitAnalysis.to_records`` as a CSV file (header from the first row)."""
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def analyse(trial: Path, out: Path) -> dict[str, object]:
    """The whole walk-through on one file; returns what it printed, for tests."""
    feet = load_feet(trial)  # left=/right=/up=/units= override the detection
    print(f"{trial.name}: {feet}")

    ga = GaitAnalysis("heelstrike").fit(feet)  # Zeni events: strikes and offs, as Nexus
    print("\nsummary (mean ± SD; L / R)")
    for row in ga.to_records("summary"):
        sd = f" ± {row['sd']:.3f}" if row["sd"] is not None else ""
        lr = (f"   L {row['left_mean']:.3f} / R {row['right_mean']:.3f}"
              if row["left_mean"] is not None and row["right_mean"] is not None else "")
        print(f"  {row['parameter']:<20} {row['mean']:.3f}{sd}{lr}"
              if row["mean"] is not None else f"  {row['parameter']:<20} —")

    out.mkdir(parents=True, exist_ok=True)
    steps = ga.to_records("steps")
    write_csv(out / "steps.csv", steps)
    write_csv(out / "events.csv", ga.to_records("events"))
    print(f"\n{len(steps)} steps → {out / 'steps.csv'} (pandas: pd.DataFrame(rows))")

    timing: dict[str, list[float]] = {}
    if feet.events:
        print("\nevent timing against the file's annotated events (detected − annotated)")
        for det, ref in match_events(ga.events_, feet.events, max_dt_s=0.1):
            dt_ms = 1000.0 * (det.time_s - ref.time_s)
            timing.setdefault(det.kind, []).append(dt_ms)
            print(f"  {ref.time_s:7.3f} s  {det.side} {det.kind:<11} {dt_ms:+6.1f} ms")
        for kind, d in timing.items():
            print(f"  {kind}: n {len(d)}, mean {np.mean(d):+.1f} ms, "
                  f"max |error| {np.max(np.abs(d)):.1f} ms")
    else:
        print("\nthe file annotates no events: nothing to compare the timing with")
    return {"summary": ga.summary_, "steps": steps, "timing_ms": timing}


def main(argv: list[str] | None = None) -> int:
    """Command line: see the module docstring."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("trial", type=Path, nargs="?", default=DEFAULT_TRIAL,
                        help="a .c3d, .trc or skeleton .csv file (default: the Vicon trial "
                             "of ../shared/data)")
    parser.add_argument("--out", type=Path, default=Path("vicon_trial_out"),
                        help="folder for steps.csv and events.csv")
    args = parser.parse_args(argv)
    try:
        analyse(args.trial, args.out)
    except GaitrigError as exc:  # a bad file or too little walking: the message says why
        print(f"vicon_trial: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
