"""The demo's recordings, every one it can make: steps found and step errors (one JSON line).

``gaitrig demo`` records the simulated walker wherever the wall clock falls in its 600 s
walk (``app.nodes.backends.sim.WORLD_CYCLE_S``: standing start, then back and forth
through the six-sensor avenue), so a recording may hold a turn, a pass seen from one end,
the far leg hidden from one side. This replays 14 s windows starting every ``--every`` s
of that walk offline, as the nodes observe it (``observe_skeletons`` on each sensor's
jittered ~30 Hz clock, world frame, back-facing frames un-mirrored as the server does),
and analyses each as the Reports page does (``integrate_skeletons`` + crossing method):
all six sensors (``weighted``, ours), the left sensors alone and the right ones alone
(one-sided), and the paper's equal-weight ``mean`` of all six as the peer. Each step is
matched to the walker's true step (same foot, within 0.2 s; the truth is the same
analysis of the true joints at 100 Hz).

Printed per configuration: windows refused (fewer than two steps), steps found per
window, the share of found steps that match a true one, and the 95th percentile and
maximum of |length error|, |width error| (cm) and |step time error| (ms); and the
ratio of six-sensor steps to one-sided steps (one side never finds more than all six
except at a pass's ends), and our six-sensor 95th percentiles over the peer's.

Usage: ``python bench/demo_windows.py [--every S] [--seed N]`` (default every 5 s, seed
0: 118 windows, ≈ 1 min on an idle core).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.nodes.backends.sim import WORLD_CYCLE_S
from app.server.analysis import unmirror_back_facing
from engine.errors import GaitrigError
from engine.gait import GaitAnalysis
from engine.geometry import transform_points
from engine.integration import SensorStream, integrate_skeletons
from engine.mocap import feet_from_skeleton
from engine.sim.clock import frame_times
from engine.sim.rig import default_avenue_rig
from engine.sim.skeleton_model import observe_skeletons
from engine.sim.walker import Walker, WalkerParams
from engine.skeleton import KINECT_V2, SkeletonSeries, TrackingState

RECORD_S = 14.0
CONFIGS: dict[str, tuple[str, tuple[str, ...] | None]] = {
    "six_weighted": ("weighted", None),
    "left_weighted": ("weighted", ("S1", "S3", "S5")),
    "right_weighted": ("weighted", ("S2", "S4", "S6")),
    "six_mean_peer": ("mean", None),
}


def _streams(rig: Any, walker: Walker, seed: int, w0: float) -> list[SensorStream]:
    """The six sensors' skeletons of true times [w0, w0 + RECORD_S), world frame, on the
    window's time axis (clocks ideal: their correction is benchmarked elsewhere)."""
    out = []
    for k in range(1, 7):
        sensor = rig.sensor(f"S{k}")
        rng = np.random.default_rng([seed, k, int(w0)])
        tw = frame_times(w0, w0 + RECORD_S, rng, fps=30)
        s = observe_skeletons(sensor, rig, walker, tw, rng)
        T = np.asarray(sensor.T_world_sensor, dtype=float)
        P = transform_points(T, s.positions.reshape(-1, 3)).reshape(s.positions.shape)
        world = SkeletonSeries(np.asarray(s.meta["times_true"]) - w0, P, s.states,
                               s.joint_set)
        world, _ = unmirror_back_facing(world, T[:3, 3])
        # back into the sensor's frame with its pose, as the server does (the weighted
        # fusion weighs each sensor by where it stands)
        Ti = np.linalg.inv(T)
        local = transform_points(Ti, world.positions.reshape(-1, 3)).reshape(P.shape)
        out.append(SensorStream(SkeletonSeries(world.times, local, world.states,
                                               world.joint_set), T, 0.0, 0.0, f"S{k}"))
    return out


def _errors(ga: GaitAnalysis, ref: GaitAnalysis) -> tuple[int, list[tuple[float, float,
                                                                           float]]]:
    """Steps found, and (length, width, time) errors of those matched to a true step."""
    errs = []
    for s in ga.steps_:
        near = [r for r in ref.steps_ if r.side == s.side and abs(r.time_s - s.time_s) < 0.2]
        if near:
            r = min(near, key=lambda r: abs(r.time_s - s.time_s))
            errs.append((s.length_m - r.length_m, s.width_m - r.width_m,
                         s.duration_s - r.duration_s))
    return len(ga.steps_), errs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--every", type=float, default=5.0, help="window spacing (s)")
    ap.add_argument("--seed", type=int, default=0, help="demo seed (rig, walker, errors)")
    args = ap.parse_args()
    t_start = time.perf_counter()
    rig = default_avenue_rig(args.seed)
    walker = Walker(WalkerParams.random(np.random.default_rng(args.seed)), rig.walkway.start,
                    rig.walkway.end, start_time=0.0, seed=args.seed,
                    horizon_s=WORLD_CYCLE_S + RECORD_S)
    starts = np.arange(0.0, WORLD_CYCLE_S - RECORD_S, args.every)
    found: dict[str, list[int]] = {c: [] for c in CONFIGS}
    errs: dict[str, list[tuple[float, float, float]]] = {c: [] for c in CONFIGS}
    refused = {c: 0 for c in CONFIGS}
    for w0 in starts:
        streams = _streams(rig, walker, args.seed, float(w0))
        t = np.arange(0.0, RECORD_S, 0.01)
        J = walker.joints(t + w0)
        truth = SkeletonSeries(t, J, np.full(J.shape[:2], TrackingState.TRACKED, np.uint8),
                               KINECT_V2)
        ref = GaitAnalysis("crossing").fit(feet_from_skeleton(truth))
        for name, (estimator, sensors) in CONFIGS.items():
            try:
                fused, _ = integrate_skeletons(streams, estimator,  # type: ignore[arg-type]
                                               sensors=sensors)
                n, e = _errors(GaitAnalysis("crossing").fit(feet_from_skeleton(fused)), ref)
            except GaitrigError:
                refused[name] += 1
                n, e = 0, []
            found[name].append(n)
            errs[name] += e
    out: dict[str, Any] = {"bench": "demo_windows", "seed": args.seed,
                           "windows": len(starts), "record_s": RECORD_S}
    for name in CONFIGS:
        e = np.abs(np.array(errs[name], dtype=float).reshape(-1, 3))
        n_found = int(np.sum(found[name]))
        out[name] = {
            "refused": refused[name],
            "steps_per_window": round(float(np.mean(found[name])), 2),
            "matched_pct": round(100.0 * len(e) / max(n_found, 1), 1),
            "length_cm_p95_max": [round(100 * float(np.percentile(e[:, 0], 95)), 1),
                                  round(100 * float(e[:, 0].max()), 1)] if len(e) else None,
            "width_cm_p95_max": [round(100 * float(np.percentile(e[:, 1], 95)), 1),
                                 round(100 * float(e[:, 1].max()), 1)] if len(e) else None,
            "time_ms_p95_max": [round(1000 * float(np.percentile(e[:, 2], 95))),
                                round(1000 * float(e[:, 2].max()))] if len(e) else None,
        }
    six = np.array(found["six_weighted"], dtype=float)
    for side in ("left", "right"):
        one = np.array(found[f"{side}_weighted"], dtype=float)
        out[f"six_vs_{side}_steps_ratio"] = round(float(six.sum() / max(one.sum(), 1.0)), 2)
        out[f"windows_{side}_finds_more_than_six"] = int(np.sum(one > six))
    ours, peer = out["six_weighted"], out["six_mean_peer"]
    out["six_weighted_vs_mean_p95_ratio"] = {
        k: round(ours[k][0] / peer[k][0], 2) if ours[k] and peer[k] and peer[k][0] else None
        for k in ("length_cm_p95_max", "width_cm_p95_max", "time_ms_p95_max")}
    out["elapsed_s"] = round(time.perf_counter() - t_start, 1)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
