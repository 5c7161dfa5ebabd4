"""``gaitrig calibrate --rig RIG``: spatial calibration on the simulation, scored.

Renders colour + noisy depth of the rig's floor markers from every simulated sensor,
detects the markers, computes 3D corners, chains (seed paper), jointly optimises the
sensor poses and refines them by ICP of the depth clouds (kept only where it improves;
fitness and inlier RMSE reported), and prints per sensor the position and rotation error
against the true pose of the chained, the optimised and the final (after ICP) estimate.
``RIG`` is ``default`` (the seed paper's avenue) or a rig file (TOML/JSON, see
``engine.sim.rig.save_rig``). Errors: one line on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any

HELP = "spatial calibration of a simulated rig; errors of chained and optimised poses"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's options."""
    parser.add_argument("--rig", default="default",
                        help="'default' (six-sensor avenue) or a rig .toml/.json file")
    parser.add_argument("--seed", type=int, default=0, help="seed of the depth noise (default 0)")
    parser.add_argument("--frames", type=int, default=30,
                        help="frames averaged per sensor (default 30)")
    parser.add_argument("--no-noise", action="store_true", help="noise-free depth")
    parser.add_argument("--no-floor-prior", action="store_true",
                        help="do not assume the markers lie on marker 1's floor plane")
    parser.add_argument("--no-icp", action="store_true",
                        help="skip the ICP refinement of the optimised poses")
    parser.add_argument("--save", metavar="FILE", help="also save the calibration as JSON")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def report(args: argparse.Namespace) -> dict[str, Any]:
    """Run the simulated calibration and return the JSON-ready report.

    Raises:
        GaitrigError: bad rig, or the calibration failed (e.g. unreachable sensors).
    """
    from engine.calibration.pipeline import FLOOR_SIGMA_M, calibrate_frames
    from engine.calibration.simcapture import pose_errors, simulate_capture
    from engine.calibration.store import save_calibration
    from engine.errors import InputError
    from engine.sim.rig import default_avenue_rig, load_rig

    if args.frames < 1 or args.frames > 300:
        raise InputError("--frames must be between 1 and 300")
    rig = default_avenue_rig(args.seed) if args.rig == "default" else load_rig(args.rig)
    t0 = time.perf_counter()
    frames = simulate_capture(rig, args.frames, args.seed, noise=not args.no_noise)
    t1 = time.perf_counter()
    res = calibrate_frames(frames, {m.id: m.size_m for m in rig.markers},
                           floor_sigma_m=None if args.no_floor_prior else FLOOR_SIGMA_M,
                           icp=not args.no_icp)
    t2 = time.perf_counter()
    if args.save:
        save_calibration(res, args.save)
    errs = pose_errors(res, rig)
    return {
        "rig": args.rig, "seed": args.seed, "frames": args.frames,
        "sensors": {s: {k: round(v, 6) for k, v in e.items()} for s, e in errs.items()},
        "max_pos_m": {k: max(e[f"{k}_pos_m"] for e in errs.values())
                      for k in ("chained", "optimised", "final")},
        "max_rot_deg": {k: max(e[f"{k}_rot_deg"] for e in errs.values())
                        for k in ("chained", "optimised", "final")},
        "icp": res.meta.get("icp", []),
        "sensor_residual_m": res.sensor_residual_m,
        "rejected": [o.to_dict() for o in res.rejected],
        "time_s": {"render": round(t1 - t0, 3), "calibrate": round(t2 - t1, 3)},
    }


def run(args: argparse.Namespace) -> int:
    """Print the report (JSON or a table)."""
    from engine.errors import GaitrigError

    try:
        doc = report(args)
    except GaitrigError as exc:
        print(f"gaitrig calibrate: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"gaitrig calibrate: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(doc))
        return 0
    print(f"{'sensor':<8}{'chained mm':>12}{'chained °':>11}{'optimised mm':>14}"
          f"{'optimised °':>13}{'final mm':>10}{'final °':>9}")
    for s, e in doc["sensors"].items():
        print(f"{s:<8}{e['chained_pos_m'] * 1000:>12.2f}{e['chained_rot_deg']:>11.3f}"
              f"{e['optimised_pos_m'] * 1000:>14.2f}{e['optimised_rot_deg']:>13.3f}"
              f"{e['final_pos_m'] * 1000:>10.2f}{e['final_rot_deg']:>9.3f}")
    for r in doc["icp"]:
        fit = (f" (fitness {r['fitness_before']:.2f}→{r['fitness']:.2f}, inlier RMSE "
               f"{r['inlier_rmse_before_mm']:.1f}→{r['inlier_rmse_mm']:.1f} mm)"
               if "fitness" in r else "")
        print(f"ICP {r['sensor']}: {'kept' if r['accepted'] else 'not kept'}: {r['reason']}{fit}")
    for o in doc["rejected"]:
        print(f"rejected {o['sensor']} marker {o['marker']}: {o['reason']}")
    print(f"render {doc['time_s']['render']:.1f} s, calibration {doc['time_s']['calibrate']:.1f} s")
    return 0
