"""How far a simulated Kinect ankle wanders while its foot stands still, one JSON line.

A standing foot does not move, but the fused Kinect ankle of the simulated study does:
this measures by how much, where it comes from, and how it reaches the paper's
placements. For each walk of the study's protocol (``bench/gait_study.py``: walkers from
``WalkerParams.random``, standing start, the six-sensor avenue, the study's clocks and
registration yaw) every true stance of a normal walking step (walker kinds ``"walk"``)
is cut at its **flat** part, from foot flat to heel rise, where the true ankle is exactly
still (the walker's ankle moves only in the heel and forefoot rockers); the fused ankle
over that interval (30 Hz, 6 Hz zero-phase filter, the study's own
``integrate_skeletons``) is compared with the true, still one. Reported per
configuration (one-sided = left sensors S1/S3/S5, two-sided = all six; ``mean`` = the
paper's equal-weight mean of TRACKED joints, ``weighted`` = ours) and foot (one-sided, L
is the near foot, R the far one):

* ``sd_cm``: within-stance SD of the fused ankle, along / across the walkway (pooled over
  stances: the root mean within-stance variance), i.e. how much it moves while standing;
* ``range_cm``: median and 90th percentile of the horizontal extent (largest distance
  between two samples) of the fused ankle within a stance;
* ``err_sd_cm``: SD over stances of the stance-mean error (fused − true), along / across:
  the placement error a stance carries as a whole, for comparison;
* ``seen``: fraction of the flat-stance samples with a fused estimate (tracked or
  gap-filled).

Also the same over the WHOLE stance (heel strike to toe off) of the true ankle, which
moves there by itself (heel rocker, push-off), to tell a true movement from a tracker
error: ``true_range_full_cm``.

Variants (``--variants``, JSON list of ``SkeletonErrorModel`` overrides; default: the
defaults, the slow fit error alone, the biases alone, visibility alone) run on common
random numbers, as ``bench/gait_error_budget.py``, so that their difference is the
effect of the terms. Usage: ``python bench/sim_stance_wander.py [--subjects 10]
[--walks 3] [--seed 0] [--variants '[{}, …]']``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.gait_error_budget import _observe
from bench.gait_study import ONE_SIDED, REGISTRATION_YAW_DEG, STANDING_S, _walk, _yaw
from engine.errors import GaitrigError
from engine.integration import integrate_skeletons
from engine.sim.rig import default_avenue_rig
from engine.sim.skeleton_model import SkeletonErrorModel
from engine.sim.walker import WalkerParams
from engine.skeleton import KINECT_V2

FloatArray = NDArray[np.float64]
#: flat part of a stance (true ankle still), whole stance, the 1 s standing start
INTERVALS = ("flat", "stance", "standing")
_ANKLE = {"L": KINECT_V2.index("AnkleLeft"), "R": KINECT_V2.index("AnkleRight")}
#: The error terms one at a time (everything else as ``SkeletonErrorModel.perfect``).
_PERFECT = {"slow_sd_m": 0.0, "jitter_sd_m": 0.0, "surface_bias_near_m": 0.0,
            "surface_bias_far_m": 0.0, "surface_bias_mid_m": 0.0, "occlusion_pull_m": 0.0,
            "inferred_sd_m": 0.0, "leg_swap_rate_hz": 0.0}
DEFAULT_VARIANTS: list[dict[str, Any]] = [
    {},
    {**_PERFECT, "slow_sd_m": SkeletonErrorModel.slow_sd_m},
    {**_PERFECT, "jitter_sd_m": SkeletonErrorModel.jitter_sd_m},
    {**_PERFECT, "surface_bias_near_m": SkeletonErrorModel.surface_bias_near_m,
     "surface_bias_far_m": SkeletonErrorModel.surface_bias_far_m,
     "surface_bias_mid_m": SkeletonErrorModel.surface_bias_mid_m},
    {**_PERFECT, "occlusion_pull_m": SkeletonErrorModel.occlusion_pull_m},
    {**_PERFECT, "inferred_sd_m": SkeletonErrorModel.inferred_sd_m},
    dict(_PERFECT),
]


def _extent(xy: FloatArray) -> float:
    """Largest distance between two rows of ``xy`` (N, 2)."""
    d = xy[:, None, :] - xy[None, :, :]
    return float(np.sqrt(np.max(np.sum(d * d, axis=-1))))


def stance_wander(t: FloatArray, ankle: FloatArray, truth: FloatArray,
                  stances: list[tuple[float, float]], axis: FloatArray
                  ) -> list[dict[str, float]]:
    """Per interval: the fused ankle's movement and error while the foot stands.

    Args:
        t: ``(T,)`` fused times (s, true clock).
        ankle: ``(T, 3)`` fused ankle (lab frame, NaN where missing).
        truth: ``(T, 3)`` true ankle at ``t`` (lab frame).
        stances: ``(t0, t1)`` of each interval.
        axis: ``(2,)`` unit walking direction (along); across is its left normal.

    Returns:
        One dict per interval with at least three samples: ``seen`` (fraction of samples
        with a fused estimate) and, with at least three of those, ``var_along``,
        ``var_across`` (within-interval variances of the fused ankle, m²), ``range``
        (its horizontal extent, m), ``err_range`` (extent of fused − true, m),
        ``err_along``, ``err_across`` (interval-mean error, m).
    """
    nrm = np.array([-axis[1], axis[0]])
    out = []
    for t0, t1 in stances:
        w = (t >= t0) & (t <= t1)
        if w.sum() < 3:
            continue
        xy = ankle[w, :2]
        ok = np.isfinite(xy).all(axis=1)
        if ok.sum() < 3:
            out.append({"seen": float(ok.mean())})
            continue
        xy = xy[ok]
        err = xy - truth[w][ok, :2]
        e = err.mean(axis=0)
        out.append({"var_along": float(np.var(xy @ axis, ddof=1)),
                    "var_across": float(np.var(xy @ nrm, ddof=1)),
                    "range": _extent(xy), "err_range": _extent(err),
                    "err_along": float(e @ axis), "err_across": float(e @ nrm),
                    "seen": float(ok.mean())})
    return out


def _summary(rows: list[dict[str, float]]) -> dict[str, Any]:
    full = [r for r in rows if "range" in r]
    if len(full) < 3:
        return {"n": len(full)}

    def col(k: str) -> FloatArray:
        return np.array([r[k] for r in full])

    def med_p90(k: str) -> list[float]:
        return [round(100 * float(np.median(col(k))), 2),
                round(100 * float(np.percentile(col(k), 90)), 2)]

    return {"n": len(full),
            "sd_cm": [round(100 * float(np.sqrt(col("var_along").mean())), 2),
                      round(100 * float(np.sqrt(col("var_across").mean())), 2)],
            "range_cm": med_p90("range"), "err_range_cm": med_p90("err_range"),
            "err_sd_cm": [round(100 * float(np.std(col("err_along"), ddof=1)), 2),
                          round(100 * float(np.std(col("err_across"), ddof=1)), 2)],
            "seen": round(float(np.mean([r["seen"] for r in rows])), 3)}


def run(n_subjects: int, n_walks: int, seed: int, variants: list[dict[str, Any]]
        ) -> dict[str, Any]:
    """Per variant, configuration and foot: the stance wander summary (see module doc)."""
    rng = np.random.default_rng(seed)
    rig = default_avenue_rig(seed=seed)
    R_inv = np.linalg.inv(_yaw(REGISTRATION_YAW_DEG))
    walks = []
    true_full: dict[str, list[float]] = {"L": [], "R": []}
    for subj in range(n_subjects):
        params = WalkerParams.random(rng)
        for walk in range(n_walks):
            w, t_end = _walk(params, seed=1000 * subj + walk)
            fps = [f for f in w.foot_placements(0.0, t_end)
                   if f.kind == "walk" and f.toe_off_s < t_end]
            T = params.step_time_s
            # still part of each stance: foot flat .. heel rise (walker: 0.5 T before
            # toe off); the whole stance (heel strike .. toe off); the standing start
            ivals = {
                "flat": {s: [(f.foot_flat_s, f.toe_off_s - 0.5 * T) for f in fps
                             if f.side == s] for s in "LR"},
                "stance": {s: [(f.time_s, f.toe_off_s) for f in fps if f.side == s]
                           for s in "LR"},
                "standing": {s: [(0.0, STANDING_S)] for s in "LR"},
            }
            for f in fps:
                tt = np.arange(f.time_s, f.toe_off_s, 0.01)
                a = w.joints(tt)[:, _ANKLE[f.side], :2]
                true_full[f.side].append(_extent(a))
            walks.append((subj, walk, w, t_end, ivals))
    out: dict[str, Any] = {"true_range_full_cm": {
        s: round(100 * float(np.median(v)), 1) for s, v in true_full.items()}}
    axis = np.array([1.0, 0.0])
    for vi, over in enumerate(variants):
        model = SkeletonErrorModel(**over)
        rows: dict[str, list[dict[str, float]]] = {
            f"{kind} {side} {est} {f}": [] for kind in INTERVALS for side in ("one", "two")
            for est in ("mean", "weighted") for f in "LR"}
        for subj, walk, w, t_end, ivals in walks:
            streams = _observe(w, t_end, rig, model, (seed, subj, walk))
            for side in ("one", "two"):
                use = streams if side == "two" else [s for s in streams
                                                     if s.sensor_id in ONE_SIDED]
                for est in ("mean", "weighted"):
                    try:
                        fused, _ = integrate_skeletons(use, est)  # type: ignore[arg-type]
                    except GaitrigError:
                        continue
                    P = fused.positions
                    lab = P @ R_inv[:3, :3].T  # undo the registration yaw
                    truth = w.joints(fused.times)
                    for kind in INTERVALS:
                        for f in "LR":
                            rows[f"{kind} {side} {est} {f}"] += stance_wander(
                                fused.times, lab[:, _ANKLE[f]], truth[:, _ANKLE[f]],
                                ivals[kind][f], axis)
        out[f"v{vi}"] = {"model": over, **{k: _summary(v) for k, v in rows.items()}}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--subjects", type=int, default=10)
    ap.add_argument("--walks", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--variants", default=None,
                    help="JSON list of SkeletonErrorModel overrides ({} = defaults); "
                         "default: the defaults and each error term alone")
    args = ap.parse_args()
    variants = DEFAULT_VARIANTS if args.variants is None else json.loads(args.variants)
    if not isinstance(variants, list) or not all(isinstance(v, dict) for v in variants):
        ap.error("--variants must be a JSON list of objects")
    t0 = time.perf_counter()
    out: dict[str, Any] = {"bench": "sim_stance_wander", "subjects": args.subjects,
                           "walks": args.walks, "seed": args.seed, "units": "cm",
                           "columns": "sd_cm/err_sd_cm: [along, across]; range_cm: "
                                      "[median, p90]"}
    out.update(run(args.subjects, args.walks, args.seed, variants))
    out["elapsed_s"] = round(time.perf_counter() - t0, 1)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
