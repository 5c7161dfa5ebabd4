"""Gait parameters of every mocap/skeleton file in a folder, one summary row per file.

    .venv/bin/python examples/batch_gait.py FOLDER [--method crossing|heelstrike]
        [--out summary.csv] [--steps steps.csv]

Every ``.c3d``, ``.trc`` and skeleton ``.csv`` under ``FOLDER`` (recursively) is analysed
with the same method. A file that cannot be analysed (no foot markers, too little
walking, a unit that contradicts the body ...) does not stop the batch: its row keeps
the engine's message in ``error``, which says what to fix. ``--steps`` writes every
step of every file, with the file's name, for your own statistics (mixed models,
variability).
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path
from typing import Any

from engine import GaitAnalysis, GaitrigError, load_feet

#: summary parameters written per file (means; the full table: GaitAnalysis.to_records)
COLUMNS = ("walking_speed_m_s", "cadence_steps_min", "step_length_m", "step_width_m",
           "step_time_s", "stride_length_m", "stride_time_s", "stance_pct",
           "double_support_pct")


def analyse_folder(folder: Path, method: str = "crossing"
                   ) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """``(one summary row per file, every step with its file)``, files in name order."""
    files = sorted(p for p in folder.rglob("*")
                   if p.is_file() and p.suffix.lower() in (".c3d", ".trc", ".csv"))
    rows: list[dict[str, Any]] = []
    steps: list[dict[str, Any]] = []
    for f in files:
        name = str(f.relative_to(folder))
        row: dict[str, Any] = {"file": name, "error": "", "n_steps": 0}
        try:
            ga = GaitAnalysis(method).fit(load_feet(f))  # type: ignore[arg-type]
        except GaitrigError as exc:
            row["error"] = str(exc)
            rows.append(row)
            continue
        summary = {r["parameter"]: r for r in ga.to_records("summary")}
        row["n_steps"] = ga.summary_["n_steps"]
        for key in COLUMNS:
            row[key] = summary[key]["mean"] if key in summary else None
        rows.append(row)
        steps += [{"file": name, **s} for s in ga.to_records("steps")]
    return rows, steps


def _write(path: Path, rows: list[dict[str, Any]]) -> None:
    fields = list(dict.fromkeys(k for r in rows for k in r))  # every key, first-seen order
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=fields)
        w.writeheader()
        w.writerows(rows)


def main(argv: list[str] | None = None) -> int:
    """Command line: see the module docstring."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--method", choices=["crossing", "heelstrike"], default="crossing")
    parser.add_argument("--out", type=Path, default=Path("summary.csv"))
    parser.add_argument("--steps", type=Path, help="also write every step to this CSV")
    args = parser.parse_args(argv)
    if not args.folder.is_dir():
        parser.error(f"{args.folder} is not a folder")
    rows, steps = analyse_folder(args.folder, args.method)
    if not rows:
        print(f"batch_gait: no .c3d, .trc or .csv file under {args.folder}", file=sys.stderr)
        return 2
    _write(args.out, rows)
    if args.steps is not None and steps:
        _write(args.steps, steps)
    failed = [r for r in rows if r["error"]]
    print(f"{len(rows) - len(failed)} of {len(rows)} files analysed → {args.out}")
    for r in failed:
        print(f"  {r['file']}: {r['error']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
