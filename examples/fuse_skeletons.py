"""Several depth sensors' skeletons of one walk fused into one world skeleton.

    .venv/bin/python examples/fuse_skeletons.py [--steps N] [--seed S]

Six simulated sensors of the seed paper's avenue each report a Kinect-v2-like skeleton
in their own camera frame, on their own clock (offset, drift), with noise and the far
leg pulled towards the sensor. :func:`engine.integrate_skeletons` corrects the clocks,
places every stream with its ``T_world_sensor``, resamples to 30 Hz, fuses and low-pass
filters. The script compares the paper's estimator (``"mean"``), gaitrig's
(``"weighted"``) and a one-sided subset of sensors against the walk's ground truth:
ankle position error (cm) and step length / width (m) from :class:`engine.GaitAnalysis`.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

import numpy as np

from engine import GaitAnalysis, GaitrigError, integrate_skeletons
from engine.sim import six_sensor_streams, synth_walk, walk_skeleton


def fuse_walk(n_steps: int = 14, seed: int = 0) -> dict[str, dict[str, Any]]:
    """Fuse the six sensors' skeletons three ways and score each against the truth.

    Args:
        n_steps: Strikes in the simulated straight walk (step length 0.70 m, width 0.12 m).
        seed: Seed of the sensors' noise and clocks.

    Returns:
        Variant name (``mean``, ``weighted``, ``one-sided``) -> ``ankle_rms_cm`` (fused
        ankles against the truth on the fused time grid), ``step_length_m`` and
        ``step_width_m`` (means over the detected steps) and ``sensors`` (ids used).

    Raises:
        InsufficientDataError: too few steps to analyse (fewer than about four).
    """
    walk = synth_walk(step_length=0.70, step_width=0.12, n_steps=n_steps)
    truth = walk_skeleton(walk)  # (T, 25, 3) world, on walk.times
    streams = six_sensor_streams(walk, np.random.default_rng(seed))
    print(f"{len(streams)} sensors; clock offsets (s): "
          + ", ".join(f"{s.sensor_id} {s.clock_offset_s:+.2f}" for s in streams))
    variants = {"mean": dict(estimator="mean"), "weighted": dict(estimator="weighted"),
                "one-sided": dict(estimator="weighted", sensors=["S1", "S3", "S5"])}
    out: dict[str, dict[str, Any]] = {}
    print(f"\ntruth: step length {walk.step_length:.3f} m, width {walk.step_width:.3f} m")
    print("variant     ankle RMS   step length   step width   sensors")
    for name, kwargs in variants.items():
        fused, report = integrate_skeletons(streams, **kwargs)  # type: ignore[arg-type]
        errs = []
        for joint in ("AnkleLeft", "AnkleRight"):
            j = fused.joint_set.index(joint)
            ref = np.stack([np.interp(fused.times, walk.times, truth[:, j, k])
                            for k in range(3)], axis=1)
            d = np.linalg.norm(fused.joint(joint) - ref, axis=1)
            errs.append(d[np.isfinite(d)])
        rms_cm = float(np.sqrt(np.mean(np.concatenate(errs) ** 2)) * 100)
        summary = GaitAnalysis().fit(fused).summary_
        row = {"ankle_rms_cm": rms_cm,
               "step_length_m": summary["step_length_m"]["mean"],
               "step_width_m": summary["step_width_m"]["mean"],
               "sensors": sorted(report.sensors_contributing)}
        out[name] = row
        print(f"{name:<10}  {rms_cm:6.2f} cm   {row['step_length_m']:8.3f} m   "
              f"{row['step_width_m']:7.3f} m   {', '.join(row['sensors'])}")
    print(f"\nfused skeleton: {fused}")
    return out


def main(argv: list[str] | None = None) -> int:
    """Command line: see the module docstring. Returns the exit code."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=14, help="strikes in the walk (default 14)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    try:
        fuse_walk(args.steps, args.seed)
    except GaitrigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
