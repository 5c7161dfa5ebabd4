"""Speed of the gait pipeline on a 10 s six-sensor recording (one JSON line).

Integration (clock correction, 30 Hz resampling, fusion, 6 Hz filter) plus gait analysis
(crossing method) of a synthetic walk seen by the seed paper's six-sensor avenue at
~30 Hz. Goal: ≤ 0.2 s for our weighted estimator; the paper's equal-weight mean is the
peer measured in the same run.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from engine.gait import GaitAnalysis
from engine.integration import integrate_skeletons
from engine.mocap import feet_from_skeleton
from engine.sim.straight_walk import six_sensor_streams, synth_walk

GOAL_S = 0.2


def _analyse(streams: list, estimator: str) -> tuple[float, int]:  # type: ignore[type-arg]
    t0 = time.perf_counter()
    fused, _ = integrate_skeletons(streams, estimator)  # type: ignore[arg-type]
    g = GaitAnalysis("crossing").fit(feet_from_skeleton(fused))
    return time.perf_counter() - t0, len(g.steps_)


def main() -> None:
    rng = np.random.default_rng(0)
    # 19 strikes at 0.55 s ≈ 10.2 s of walking at 1.27 m/s through the avenue
    w = synth_walk(step_length=0.7, step_time=0.55, n_steps=19, rate=120.0,
                   origin=(-3.0, 0.0, 0.0))
    streams = six_sensor_streams(w, rng)
    frames = sum(len(s.series) for s in streams)
    res: dict[str, float] = {}
    steps = 0
    for est in ("mean", "weighted"):
        _analyse(streams, est)  # warm-up (imports, caches)
        times = []
        for _ in range(5):
            dt, steps = _analyse(streams, est)
            times.append(dt)
        res[est] = float(np.median(times))
    print(json.dumps({
        "bench": "gait_speed",
        "recording_s": round(float(w.times[-1] - w.times[0]), 2),
        "sensors": len(streams),
        "frames_in": frames,
        "steps": steps,
        "weighted_s": round(res["weighted"], 4),
        "mean_peer_s": round(res["mean"], 4),
        "ratio_weighted_vs_mean": round(res["weighted"] / res["mean"], 2),
        "goal_s": GOAL_S,
        "meets_goal": res["weighted"] <= GOAL_S,
    }))


if __name__ == "__main__":
    main()
