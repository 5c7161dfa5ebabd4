"""Error budget of the simulated study with the paper's averaging, one JSON line.

``bench/gait_study.py`` judges the simulation by each row's step-level ICC(A,1), which
one sample of ten subjects moves by up to ±0.2. The error variance of each row (var of
Kinect − reference) and its bias are far steadier, and they are what the skeleton error
model actually sets. This harness reports, for the paper's method only (equal-weight mean
of TRACKED joints, placement at the crossing instant, walkway axis; the study's own
functions), per row of Tables 2–3 (one-/two-sided step length, step width, stride length,
L/R):

* ``target``: the paper's error variance (RPC/1.96)² in cm² (the paper's RPC is 1.96·SD
  of the differences, Table 1 caption; its r and SDs agree: e.g. one-sided step length L,
  6.18² + 5.36² − 2·0.667·6.18·5.36 = (9.34/1.96)²), its bias, and its Vicon SD;
* per model variant: the simulated error variance, bias, ICC(A,1) and the reference
  ("Vicon") SD of the simulated walkers (ICC cannot match unless that SD matches).

Variants (``--variants``, a JSON list of ``SkeletonErrorModel`` overrides, ``{}`` = the
defaults) are run on the same subjects and walks with common random numbers: each
sensor's observation of each walk draws from its own generator seeded by (seed, subject,
walk, sensor), so the difference between two variants is the effect of the parameters,
not of a new sample. Turning one term on at a time gives its variance contribution.

A variant may also hold ``"paper_keeps_inferred": true``: the paper's mean then keeps
INFERRED joints and drops only NOT_TRACKED ones (its Discussion's reading; see
``bench.gait_study.PAPER_KEPT_STATES``); the key is not a model field.

Usage: ``python bench/gait_error_budget.py [--subjects 10] [--walks 5] [--seed 0]
[--variants '[{}, {"far_leg_refit_sd_m": 0.02}, {"paper_keeps_inferred": true}]']``.
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

from bench.gait_study import (
    ONE_SIDED,
    PAPER_KEPT_STATES,
    PAPER_KEPT_STATES_DISCUSSION,
    REGISTRATION_YAW_DEG,
    _paper_analysis,
    _reference,
    _walk,
    _yaw,
)
from engine.agreement import agreement, match_steps
from engine.errors import GaitrigError
from engine.gait import GaitAnalysis
from engine.integration import SensorStream, integrate_skeletons
from engine.mocap import feet_from_skeleton
from engine.sim.clock import frame_times
from engine.sim.rig import default_avenue_rig
from engine.sim.skeleton_model import SkeletonErrorModel, observe_skeletons
from engine.sim.walker import WalkerParams

#: Paper's step-level rows: (Kinect SD, Vicon SD, r, bias, RPC) in cm (Tables 2–3).
PAPER_ROWS: dict[str, dict[str, tuple[float, float, float, float, float]]] = {
    "one": {"step_length L": (6.18, 5.36, 0.667, -1.10, 9.34),
            "step_length R": (8.36, 4.48, 0.538, 1.73, 13.81),
            "step_width L": (4.69, 3.15, 0.569, -1.49, 7.62),
            "step_width R": (7.33, 2.97, 0.475, 2.68, 12.69),
            "stride_length L": (11.08, 8.49, 0.786, 0.59, 13.43),
            "stride_length R": (10.22, 9.01, 0.923, -0.78, 7.77)},
    "two": {"step_length L": (5.16, 5.36, 0.833, 0.41, 5.97),
            "step_length R": (5.35, 4.48, 0.817, 0.34, 6.05),
            "step_width L": (3.88, 3.15, 0.757, -1.57, 4.98),
            "step_width R": (3.47, 2.97, 0.817, 2.24, 3.94),
            "stride_length L": (8.65, 8.49, 0.970, 0.71, 4.16),
            "stride_length R": (9.47, 9.01, 0.973, -0.52, 4.32)},
}
ROWS = list(PAPER_ROWS["one"])


def targets() -> dict[str, Any]:
    """The paper's per-row error variance (cm²), bias (cm) and Vicon SD (cm)."""
    return {side: {r: {"err_var": round((v[4] / 1.96) ** 2, 1), "bias": v[3],
                       "ref_sd": v[1]} for r, v in rows.items()}
            for side, rows in PAPER_ROWS.items()}


def _observe(w: Any, t_end: float, rig: Any, model: SkeletonErrorModel,
             key: tuple[int, ...]) -> list[SensorStream]:
    """All sensors' streams of one walk; sensor k draws from its own generator."""
    R = _yaw(REGISTRATION_YAW_DEG)
    out = []
    for k, s in enumerate(rig.sensors):
        rng = np.random.default_rng([*key, k])
        times = frame_times(0.0, t_end, rng)
        ser = observe_skeletons(s, rig, w, times, rng, model=model,
                                shared_seed=int(np.random.default_rng(list(key)).integers(2**31)))
        out.append(SensorStream(ser, R @ s.T_world_sensor, s.clock_offset_s,
                                s.clock_drift_ppm, s.id))
    return out


def _pairs(meas: list[Any], ref: list[Any], attr: str
           ) -> dict[str, tuple[list[float], list[float]]]:
    out: dict[str, tuple[list[float], list[float]]] = {"L": ([], []), "R": ([], [])}
    for m, r in match_steps(meas, ref, 0.25):
        out[m.side][0].append(100.0 * float(getattr(m, attr)))
        out[m.side][1].append(100.0 * float(getattr(r, attr)))
    return out


def _by_index(meas: list[Any], ref: list[Any], out: dict[str, list[float]], side: str
              ) -> None:
    """Step errors (cm) by the step's place in the walk: ``first`` is the first kept step
    (the first right step, R1 − L1, once the first left step is excluded), ``second`` the
    first kept left step (L2 − R1), ``later L`` / ``later R`` the rest."""
    order = {id(r): i for i, r in enumerate(ref)}
    for m, r in match_steps(meas, ref, 0.25):
        i = order[id(r)]
        where = "first" if i == 0 else "second" if i == 1 else f"later {m.side}"
        for name, attr in (("step_length", "length_m"), ("step_width", "width_m")):
            out.setdefault(f"{side} {name} {where}", []).append(
                100.0 * float(getattr(m, attr) - getattr(r, attr)))


def run(n_subjects: int, n_walks: int, seed: int, variants: list[dict[str, Any]]
        ) -> dict[str, Any]:
    """Per variant and row: error variance, bias, ICC(A,1), reference SD (cm); and the
    step rows' error variance by the step's place in the walk (``by_step``: n and cm²;
    the paper's N per walk put an error on its first left placement L1, which only the
    first kept right step and the first left stride contain)."""
    rng = np.random.default_rng(seed)
    rig = default_avenue_rig(seed=seed)
    walks = []
    for subj in range(n_subjects):
        params = WalkerParams.random(rng)
        for walk in range(n_walks):
            w, t_end = _walk(params, seed=1000 * subj + walk)
            walks.append((subj, walk, w, t_end, _reference(w, t_end, True)))
    out: dict[str, Any] = {}
    for vi, over in enumerate(variants):
        fields = dict(over)
        kept = (PAPER_KEPT_STATES_DISCUSSION if fields.pop("paper_keeps_inferred", False)
                else PAPER_KEPT_STATES)
        model = SkeletonErrorModel(**fields)
        data: dict[str, dict[str, tuple[list[float], list[float]]]] = {
            f"{side} {row}": ([], []) for side in ("one", "two") for row in ROWS}
        failed = 0
        by_step: dict[str, list[float]] = {}
        for subj, walk, w, t_end, ref in walks:
            streams = _observe(w, t_end, rig, model, (seed, subj, walk))
            for side in ("one", "two"):
                use = streams if side == "two" else [s for s in streams
                                                     if s.sensor_id in ONE_SIDED]
                try:
                    fused, _ = integrate_skeletons(use, "mean", kept_states=kept)
                    g: GaitAnalysis = _paper_analysis().fit(feet_from_skeleton(fused))
                except GaitrigError:
                    failed += 1
                    continue
                _by_index(g.steps_, ref.steps_, by_step, side)
                for name, attr, mine, theirs in (
                        ("step_length", "length_m", g.steps_, ref.steps_),
                        ("step_width", "width_m", g.steps_, ref.steps_),
                        ("stride_length", "length_m", g.strides_, ref.strides_)):
                    for s, (a, b) in _pairs(mine, theirs, attr).items():
                        data[f"{side} {name} {s}"][0].extend(a)
                        data[f"{side} {name} {s}"][1].extend(b)
        res: dict[str, Any] = {"model": over, "failed": failed}
        for key, (a, b) in data.items():
            if len(a) < 3:
                continue
            ag = agreement(a, b)
            d = np.asarray(a) - np.asarray(b)
            mad = 1.4826 * float(np.median(np.abs(d - np.median(d))))
            res[key] = {"n": len(a), "err_var": round(float(np.var(d, ddof=1)), 1),
                        "err_var_robust": round(mad**2, 1),
                        "n_out": int(np.sum(np.abs(d - np.median(d)) > 4 * mad)),
                        "bias": round(float(np.mean(d)), 2), "icc": round(ag.icc_a1, 3),
                        "ref_sd": round(float(np.std(b, ddof=1)), 2)}
        res["by_step"] = {k: [len(d), round(float(np.var(d, ddof=1)), 1)]
                          for k, d in sorted(by_step.items()) if len(d) >= 3}
        out[f"v{vi}"] = res
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--subjects", type=int, default=10)
    ap.add_argument("--walks", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--variants", default="[{}]",
                    help="JSON list of SkeletonErrorModel overrides ({} = defaults)")
    args = ap.parse_args()
    variants = json.loads(args.variants)
    if not isinstance(variants, list) or not all(isinstance(v, dict) for v in variants):
        ap.error("--variants must be a JSON list of objects")
    t0 = time.perf_counter()
    out: dict[str, Any] = {"bench": "gait_error_budget", "subjects": args.subjects,
                           "walks": args.walks, "seed": args.seed,
                           "units": "cm, cm²", "target": targets()}
    out.update(run(args.subjects, args.walks, args.seed, variants))
    out["elapsed_s"] = round(time.perf_counter() - t0, 1)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
