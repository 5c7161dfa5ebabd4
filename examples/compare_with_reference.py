"""Agreement of gaitrig with a reference system (e.g. Vicon) on the same walks, from files.

    .venv/bin/python examples/compare_with_reference.py MEASURED REFERENCE [MEASURED
        REFERENCE ...] [--offset SECONDS] [--method crossing|heelstrike] [--csv FILE]

``MEASURED``: a gaitrig export of a recording (Subjects & recordings → export: skeleton
CSV, C3D or TRC); ``REFERENCE``: the reference system's file of the same walk (C3D/TRC).
Pairs of files are trials; steps are paired per side within 0.25 s
(:func:`engine.agreement.match_steps`), so **both files must be on one time axis**: give
``--offset`` (s, added to the reference's times) when the reference started at another
instant, e.g. from a shared trigger or a sync event seen by both. Prints seed 000's
statistics (n, bias, RPC, ICC(A,1), r) for step length, width and time at the single-step
level per side, and, with ``--csv``, writes every matched pair.

Without files (``--demo``) it simulates four walks seen by the six-sensor avenue and
their "reference" markers, writes them as a gaitrig CSV export and a TRC, and compares
those — the same code path. (Its simple sensor model, ``engine.sim.straight_walk``,
pulls each sensor's far leg 4 cm towards it: step widths come out ≈ 3 cm narrower than
the reference's, a bias of the kind a real comparison shows.)
"""

from __future__ import annotations

import argparse
import csv
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

from engine import (
    GaitAnalysis,
    GaitrigError,
    InputError,
    agreement_levels,
    load_feet,
    match_steps,
)

PARAMETERS = (("length_m", "step length", "cm", 100.0), ("width_m", "step width", "cm", 100.0),
              ("duration_s", "step time", "ms", 1000.0))


def demo_files(folder: Path, n: int = 4) -> list[tuple[Path, Path]]:
    """Simulated trials written as files: (gaitrig skeleton CSV, reference TRC) pairs."""
    import numpy as np

    from engine import integrate_skeletons, write_skeleton_csv, write_trc
    from engine.sim import six_sensor_streams, synth_walk, walk_markers

    rng = np.random.default_rng(7)
    out = []
    for k in range(n):
        # walks that differ, as subjects do: agreement needs a spread of true values
        walk = synth_walk(step_length=0.58 + 0.06 * k, step_width=0.08 + 0.025 * k,
                          step_time=0.50 + 0.03 * k, n_steps=12)
        fused, _ = integrate_skeletons(six_sensor_streams(walk, rng))
        m, r = folder / f"trial{k + 1}_gaitrig.csv", folder / f"trial{k + 1}_vicon.trc"
        write_skeleton_csv(m, fused)
        write_trc(r, walk_markers(walk))
        out.append((m, r))
    return out


def compare(pairs: list[tuple[Path, Path]], offset_s: float = 0.0, method: str = "crossing",
            csv_path: Path | None = None) -> dict[str, dict[str, object]]:
    """Step-level agreement over all trials; returns ``{parameter: {level: row}}``."""
    trials = []
    for measured, reference in pairs:
        m = GaitAnalysis(method).fit(load_feet(measured)).steps_  # type: ignore[arg-type]
        r = GaitAnalysis(method).fit(load_feet(reference)).steps_  # type: ignore[arg-type]
        r = [replace(s, time_s=s.time_s + offset_s) for s in r]
        n = len(match_steps(m, r))
        print(f"{measured.name} vs {reference.name}: {len(m)} / {len(r)} steps, {n} paired")
        # Gait is periodic: a wrong offset near a whole number of strides still pairs a
        # few steps, so fewer than half of them pairing means the time axes differ.
        if n < max(2, 0.5 * min(len(m), len(r))):
            raise InputError(f"{measured.name} and {reference.name}: only {n} of "
                             f"{min(len(m), len(r))} steps pair within 0.25 s — the files "
                             "are not on one time axis; give --offset (s, added to the "
                             "reference's times)")
        trials.append((m, r))
    # Every trial as its own "subject" here: the single-step rows are what one subject
    # gives; give agreement_levels {subject: [trials]} for the subject-average rows.
    results: dict[str, dict[str, object]] = {}
    print(f"\n{'parameter':<12} {'side':<5} {'n':>3} {'bias':>9} {'RPC':>8} "
          f"{'ICC(A,1)':>8} {'r':>6}")
    for attr, label, unit, scale in PARAMETERS:
        levels = agreement_levels({f"T{k}": [t] for k, t in enumerate(trials)}, attr)
        results[attr] = {}
        for side in ("L", "R"):
            if side not in levels:
                # agreement statistics need at least three pairs: say so, not a blank row
                n = sum(s.side == side for m, r in trials for s, _ in match_steps(m, r))
                print(f"{label:<12} {side:<5} {n:>3}  too few paired steps (3 needed)")
                continue
            a = levels[side]
            results[attr][side] = a
            print(f"{label:<12} {side:<5} {a.n:>3} {a.bias * scale:>+6.2f} {unit:<2} "
                  f"{a.rpc * scale:>5.2f} {unit:<2} {a.icc_a1:>8.3f} {a.r:>6.3f}")
    print("(bias = gaitrig − reference; RPC = 1.96 SD of the differences)")
    if csv_path is not None:
        with csv_path.open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["trial", "side", "time_s", *(f"gaitrig_{p[0]}" for p in PARAMETERS),
                        *(f"reference_{p[0]}" for p in PARAMETERS)])
            for k, (m, r) in enumerate(trials):
                for a, b in match_steps(m, r):
                    w.writerow([k + 1, a.side, b.time_s, *(getattr(a, p[0]) for p in PARAMETERS),
                                *(getattr(b, p[0]) for p in PARAMETERS)])
        print(f"matched steps → {csv_path}")
    return results


def main(argv: list[str] | None = None) -> int:
    """Command line: see the module docstring."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", type=Path, nargs="*",
                        help="MEASURED REFERENCE pairs (gaitrig export, reference file)")
    parser.add_argument("--offset", type=float, default=0.0,
                        help="seconds added to the reference's times (default 0)")
    parser.add_argument("--method", choices=["crossing", "heelstrike"], default="crossing")
    parser.add_argument("--csv", type=Path, help="write the matched steps to this CSV file")
    parser.add_argument("--demo", action="store_true", help="simulated files instead")
    args = parser.parse_args(argv)
    if args.demo == bool(args.files) or len(args.files) % 2:
        parser.error("give MEASURED REFERENCE pairs of files, or --demo")
    try:
        if args.demo:
            with tempfile.TemporaryDirectory() as tmp:
                compare(demo_files(Path(tmp)), args.offset, args.method, args.csv)
        else:
            pairs = list(zip(args.files[::2], args.files[1::2], strict=True))
            compare(pairs, args.offset, args.method, args.csv)
    except GaitrigError as exc:
        print(f"compare_with_reference: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
