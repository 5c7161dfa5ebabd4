"""Spatial calibration of the simulated six-sensor avenue, scored against the truth.

    .venv/bin/python examples/calibrate_simulated.py [--frames N] [--seed S] [--icp]
        [--out calibration.json]

The simulator renders what each depth camera of the seed paper's avenue sees of the
empty room (colour with the floor's ArUco markers, noisy depth); the calibration then
does what it does with real frames: detect the markers, take their 3D corners from
depth, chain sensor → marker → sensor from marker 1 (the world origin, Z up), refine
everything jointly (and, with ``--icp``, by ICP of the depth clouds). Because the
simulator knows where each tripod really stands, every pose ``T_world_sensor`` is
printed with its position (cm) and rotation (°) error — the check a lab cannot make.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from engine import GaitrigError
from engine.calibration import (
    calibrate_frames,
    pose_errors,
    save_calibration,
    simulate_capture,
)
from engine.sim import default_avenue_rig


def calibrate_avenue(frames: int = 4, seed: int = 0, icp: bool = False,
                     out: Path | None = None) -> dict[str, dict[str, Any]]:
    """Simulate a capture, calibrate it and print each sensor's error against the truth.

    Args:
        frames: Colour + depth frames rendered per sensor (more frames: less depth noise).
        seed: Seed of the rig's noise and of the depth noise.
        icp: Refine the jointly optimised poses by ICP (slower; kept only where it helps).
        out: Where to save the calibration as JSON (nothing saved when None).

    Returns:
        Sensor id -> :func:`engine.calibration.pose_errors` row (``final_pos_m``,
        ``final_rot_deg``, ``chained_pos_m``, ... and ``distance_to_origin_m``).

    Raises:
        CalibrationError: a sensor sees no marker chain to marker 1.
    """
    rig = default_avenue_rig(seed)
    sizes = {m.id: m.size_m for m in rig.markers}
    capture = simulate_capture(rig, frames=frames, seed=seed)
    print(f"{len(capture)} sensors x {frames} frames rendered; "
          f"{len(sizes)} floor markers, edge {min(sizes.values()) * 100:.0f} cm")
    result = calibrate_frames(capture, sizes, icp=icp)
    used = sum(o.accepted for o in result.observations)
    print(f"{used} marker observations used, {len(result.rejected)} rejected")
    errors = pose_errors(result, rig)
    print("\nsensor  position (m, world)      error: chained   final")
    for sid in result.sensor_ids:
        p = result.T_world_sensor[sid][:3, 3]
        e = errors[sid]
        print(f"{sid:<6}  ({p[0]:5.2f}, {p[1]:5.2f}, {p[2]:4.2f})   "
              f"{e['chained_pos_m'] * 100:5.2f} cm {e['chained_rot_deg']:4.2f}°   "
              f"{e['final_pos_m'] * 100:5.2f} cm {e['final_rot_deg']:4.2f}°")
    if out is not None:
        save_calibration(result, out)
        print(f"\ncalibration saved to {out}")
    return errors


def main(argv: list[str] | None = None) -> int:
    """Command line: see the module docstring. Returns the exit code."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=4, help="frames per sensor (default 4)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--icp", action="store_true", help="refine by ICP of the depth clouds")
    ap.add_argument("--out", type=Path, help="save the calibration JSON here")
    args = ap.parse_args(argv)
    try:
        calibrate_avenue(args.frames, args.seed, args.icp, args.out)
    except GaitrigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
