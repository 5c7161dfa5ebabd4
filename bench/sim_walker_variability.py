"""Variability of the simulated walkers' reference gait against seed 000's Vicon, one JSON line.

The validation study (``bench/gait_study.py``) compares Kinect against a reference whose
spread sets every ICC: a walker more variable than the paper's subjects makes the
simulated ICCs too easy. This measures the reference side only (the walker's true joints
at 100 Hz, the paper's crossing analysis, ``bench/gait_study.py``'s own ``_reference``)
for subjects and walks drawn as the study draws them (``WalkerParams.random``, standing
start, the paper's exclusion rule; as in ``bench/gait_error_budget.py`` the subjects are
drawn without the sensors' draws in between, so they are not the study's own sample),
seeds ``--seed`` … ``--seed + --seeds − 1``, and splits it, per row of Tables 1–3
(step length, stride length, step time, stride time; L/R):

* ``sd``: step-level SD (all matched steps of a side, as the paper's single-step rows);
* ``av_sd``: SD of the subject averages (the paper's AV rows) and ``av_avg_sd`` over
  both sides (AV AVG);
* ``within_sd`` and ``within_cv_pct``: pooled within-subject SD (steps about their
  subject's mean of that side) and as % of the mean: the stride-to-stride variability
  that Hausdorff et al. (1999, J Appl Physiol 86:1040: stride-time CV 1.3 ± 0.1 % in
  young adults) and others report;
* ``lag1_r``: correlation of consecutive steps' lengths (times) within a walk, about
  each subject's side means: a walker that corrects a long step by a short one has
  r < 0, independent steps r ≈ 0.

``paper`` holds the same figures from the Vicon columns of Tables 1–3 (step-level and AV
SDs; within-subject SD as √(SD² − AV SD²), an estimate, as the AV SD is over ten
subjects). The figures are means over the seeds (one sample of ten subjects moves an SD
of the subject averages by ≈ ±25 %), each seed's in ``per_seed``.

Usage: ``python bench/sim_walker_variability.py [--subjects 10] [--walks 10] [--seed 0]
[--seeds 5]``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.gait_study import _reference, _walk
from engine.errors import GaitrigError
from engine.sim.walker import WalkerParams

#: Vicon columns of seed 000 (Tables 1–3): (step-level SD, AV SD, mean), cm or s.
PAPER_VICON: dict[str, tuple[float, float, float]] = {
    "step_length L": (5.36, 5.13, 73.95), "step_length R": (4.48, 3.60, 71.67),
    "stride_length L": (8.49, 7.98, 145.36), "stride_length R": (9.01, 8.43, 147.04),
    "step_time L": (0.07, 0.07, 0.61), "step_time R": (0.07, 0.06, 0.60),
}
PAPER_AV_AVG = {"step_length": 3.96, "stride_length": 8.17, "step_time": 0.07}
_ROWS = [f"{p} {s}" for p in ("step_length", "stride_length", "step_time", "stride_time")
         for s in "LR"]


def paper_figures() -> dict[str, dict[str, float]]:
    """The paper's Vicon SDs per row, with the implied within-subject SD and CV."""
    out = {}
    for row, (sd, av, mean) in PAPER_VICON.items():
        within = float(np.sqrt(max(sd**2 - av**2, 0.0)))
        out[row] = {"sd": sd, "av_sd": av, "within_sd": round(within, 3),
                    "within_cv_pct": round(100 * within / mean, 2)}
    return out


def _lag1(walks: list[list[tuple[str, float]]], means: dict[str, float]) -> float:
    """Correlation of consecutive values (about their side's subject mean) in walks."""
    a, b = [], []
    for seq in walks:
        d = [(s, v - means[s]) for s, v in seq]
        for (_, x), (_, y) in itertools.pairwise(d):
            a.append(x)
            b.append(y)
    return float(np.corrcoef(a, b)[0, 1]) if len(a) >= 3 else float("nan")


def study_variability(n_subjects: int, n_walks: int, seed: int) -> dict[str, Any]:
    """One seed's reference variability per row (cm for lengths, s for times)."""
    rng = np.random.default_rng(seed)
    vals: dict[str, dict[int, list[float]]] = {r: {} for r in _ROWS}
    per_subj_seqs: dict[str, dict[int, list[list[tuple[str, float]]]]] = {
        "step_length": {}, "step_time": {}}
    for subj in range(n_subjects):
        params = WalkerParams.random(rng)
        for walk in range(n_walks):
            w, t_end = _walk(params, seed=1000 * subj + walk)
            try:
                g = _reference(w, t_end, True)
            except GaitrigError:
                continue
            for s in g.steps_:
                vals[f"step_length {s.side}"].setdefault(subj, []).append(100 * s.length_m)
                vals[f"step_time {s.side}"].setdefault(subj, []).append(s.duration_s)
            for s in g.strides_:
                vals[f"stride_length {s.side}"].setdefault(subj, []).append(100 * s.length_m)
                vals[f"stride_time {s.side}"].setdefault(subj, []).append(s.duration_s)
            steps = sorted(g.steps_, key=lambda s: s.time_s)
            per_subj_seqs["step_length"].setdefault(subj, []).append(
                [(s.side, 100 * s.length_m) for s in steps])
            per_subj_seqs["step_time"].setdefault(subj, []).append(
                [(s.side, s.duration_s) for s in steps])
    out: dict[str, Any] = {}
    for row, by_subj in vals.items():
        allv = np.concatenate([np.asarray(v) for v in by_subj.values()])
        avs = np.array([np.mean(v) for v in by_subj.values()])
        resid = np.concatenate([np.asarray(v) - np.mean(v) for v in by_subj.values()])
        dof = len(resid) - len(by_subj)
        within = float(np.sqrt(np.sum(resid**2) / max(dof, 1)))
        out[row] = {"n": len(allv), "sd": float(np.std(allv, ddof=1)),
                    "av_sd": float(np.std(avs, ddof=1)), "within_sd": within,
                    "within_cv_pct": 100 * within / float(np.mean(allv))}
    for par in ("step_length", "step_time"):
        # subject averages over both sides (AV AVG) and the lag-1 correlation
        avg = [np.mean(vals[f"{par} L"].get(s, []) + vals[f"{par} R"].get(s, []))
               for s in range(n_subjects) if s in vals[f"{par} L"]]
        out[f"{par} AV AVG"] = {"av_sd": float(np.std(avg, ddof=1))}
        rs = []
        for subj, walks in per_subj_seqs[par].items():
            means = {sd: float(np.mean(vals[f"{par} {sd}"][subj])) for sd in "LR"
                     if subj in vals[f"{par} {sd}"]}
            if len(means) == 2:
                rs.append(_lag1(walks, means))
        out[f"{par} lag1_r"] = float(np.nanmean(rs))
    stl = [np.mean(vals["stride_length L"].get(s, []) + vals["stride_length R"].get(s, []))
           for s in range(n_subjects) if s in vals["stride_length L"]]
    out["stride_length AV AVG"] = {"av_sd": float(np.std(stl, ddof=1))}
    return out


def _mean_over(runs: list[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, v in runs[0].items():
        if isinstance(v, dict):
            out[key] = {k: round(float(np.mean([r[key][k] for r in runs])), 3)
                        for k in v}
        else:
            out[key] = round(float(np.mean([r[key] for r in runs])), 3)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--subjects", type=int, default=10)
    ap.add_argument("--walks", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--seeds", type=int, default=5)
    args = ap.parse_args()
    t0 = time.perf_counter()
    runs = [study_variability(args.subjects, args.walks, s)
            for s in range(args.seed, args.seed + max(args.seeds, 1))]
    out: dict[str, Any] = {"bench": "sim_walker_variability", "subjects": args.subjects,
                           "walks": args.walks, "seeds": [args.seed, args.seed + len(runs) - 1],
                           "units": "cm, s, %", "sim": _mean_over(runs),
                           "paper": paper_figures(), "paper_av_avg_sd": PAPER_AV_AVG,
                           "per_seed": runs}
    out["elapsed_s"] = round(time.perf_counter() - t0, 1)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
