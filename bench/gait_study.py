"""The seed paper's validation protocol in simulation (Tables 1–3), one JSON line.

10 simulated subjects (``WalkerParams.random``) × 10 walks of 7 m (from standing, left
foot first, walking on past the end so that there is no slowing down) through the
six-sensor avenue (``default_avenue_rig``), skeletons observed with the SIM error model
(``observe_skeletons``) on each sensor's own jittered ~30 Hz
clock. The Kinect side: integration (clock correction, 30 Hz, fusion, 6 Hz filter) with
the paper's equal-weight ``mean`` and its gait analysis (foot placement at the crossing
instant, lengths and widths along the walkway axis), and ours (``weighted`` fusion;
placements from the stance, walking direction from the footprints), from the left
sensors only (one-sided) and from all six (two-sided). The Kinect system's world frame is
registered to the reference lab frame with a yaw of ``REGISTRATION_YAW_DEG`` (see there).
The reference ("Vicon") side: the same crossing-based analysis on the walker's true
joints at 100 Hz in the lab frame, as the paper applied the same procedure to both
systems. Sensor poses and clock models are otherwise known (calibration is benchmarked
elsewhere). Everything is vectorised per walk (~20 s for 10 × 10 on an idle core).

Printed (one JSON line): the study is repeated for ``--seeds`` seeds (default 5: seeds
0–4; one sample of ten subjects moves a row's ICC by up to ±0.2, so one seed's band is
luck). ``realism_rows`` / ``realism_band`` / ``realism_within`` are the REPORTED figure:
per row, the mean over the seeds of the paper's-method step-level ICC(A,1) and bias,
against Tables 2–3 (``realism_figure`` says so; ``realism_within_per_seed`` gives each
seed's own count). ``ours_acceptance`` likewise on the mean over the seeds, with
``ours_acceptance_per_seed``. ``first_seed`` holds
the first seed's full study: per configuration the step-level (L/R) and subject-average
rows of step length, step width, stride length and step time (n, bias in cm or s, RPC,
ICC(A,1)), the walking speed row, and its own band.

Usage: ``python bench/gait_study.py [--subjects N] [--walks M] [--seed S] [--seeds K]
[--model JSON] [--paper-keeps-inferred]`` (defaults 10 × 10, seeds 0–4; ``--seeds 1`` for
one study as before; ``--paper-keeps-inferred``: the paper's mean keeps INFERRED joints,
see ``PAPER_KEPT_STATES``).
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

from engine.agreement import agreement, agreement_levels
from engine.errors import GaitrigError
from engine.gait import GaitAnalysis, Step, Stride
from engine.integration import SensorStream, integrate_skeletons
from engine.mocap import feet_from_skeleton
from engine.sim.clock import frame_times
from engine.sim.rig import default_avenue_rig
from engine.sim.skeleton_model import SkeletonErrorModel, observe_skeletons
from engine.sim.walker import Walker, WalkerParams
from engine.skeleton import KINECT_V2, SkeletonSeries, TrackingState

#: Paper's step-level rows (ICC(A,1), bias cm): Table 2 (one-sided), Table 3 (two-sided).
PAPER = {
    "one": {"step_length L": (0.649, -1.10), "step_length R": (0.434, 1.73),
            "step_width L": (0.493, -1.49), "step_width R": (0.297, 2.68),
            "stride_length L": (0.758, 0.59), "stride_length R": (0.913, -0.78)},
    "two": {"step_length L": (0.830, 0.41), "step_length R": (0.803, 0.34),
            "step_width L": (0.675, -1.57), "step_width R": (0.650, 2.24),
            "stride_length L": (0.966, 0.71), "stride_length R": (0.970, -0.52)},
    "step_time": {"L": (0.924, 0.0), "R": (0.925, 0.0)},
}

WALK_FROM = np.array([-0.5, 0.0, 0.0])
#: The subject keeps walking past the end of the analysed 7 m ("Subjects did not stop at
#: the end of the track volume so that there was no slowing down", seed 000, Fig. 6);
#: both systems are analysed until the pelvis has covered the 7 m.
WALK_TO = np.array([11.0, 0.0, 0.0])
WALK_M = 7.0
#: Each walk is recorded from standing: the subject stands still this long, then starts
#: with the left foot ("we asked subject to begin walking with the left foot", seed 000;
#: its Fig. 6 shows the standing start and the excluded first left step and first right
#: stride). The standing lets both systems see the standing foot's placement.
STANDING_S = 1.0
ONE_SIDED = ("S1", "S3", "S5")  # y = +1: on the subject's left when walking +X
#: Yaw (deg) of the Kinect system's calibrated world frame relative to the reference
#: ("Vicon") lab frame: two independently calibrated systems never share an axis
#: exactly. Seed 000 does not report it, but its Tables 2–3 carry its signature: left
#: and right step widths biased in opposite directions by the same amount (two-sided
#: −1.57/+2.24 cm, one-sided −1.49/+2.68 cm, i.e. ∓1.9–2.1 cm about a small common
#: part, the same with either sensor set, hence not a view effect). Widths measured
#: along a fixed lab axis that is rotated by ψ change by ∓ψ·step length: ψ ≈ −2.0 cm /
#: 73 cm ≈ −1.5°. Set from those tables before any change to our estimator.
REGISTRATION_YAW_DEG = -1.5
#: The paper's walking direction: the walkway's axis in each system's own frame (the
#: avenue was laid out along the Vicon volume); ours finds it from the footprints.
PAPER_AXIS = (1.0, 0.0)
#: Which of a sensor's tracking states the paper's equal-weight mean keeps. Its Methods:
#: "Untracked or inferred joint positions were considered as missing values" (TRACKED
#: only, the default); its Discussion: "we ignore joint positions which are labeled as
#: untracked", i.e. INFERRED kept too (``--paper-keeps-inferred``; measured and set
#: aside, see docs/simulation.md, "Also set aside: the paper's mean keeping INFERRED").
PAPER_KEPT_STATES: tuple[int, ...] = (TrackingState.TRACKED,)
PAPER_KEPT_STATES_DISCUSSION: tuple[int, ...] = (TrackingState.TRACKED,
                                                 TrackingState.INFERRED)


def _walk(params: WalkerParams, seed: int) -> tuple[Walker, float]:
    w = Walker(params, WALK_FROM, WALK_TO, start_time=STANDING_S, back_and_forth=False,
               seed=seed, horizon_s=30.0)
    t = np.arange(0.0, 20.0 + STANDING_S, 0.01)
    pelvis_x = w.joints(t)[:, KINECT_V2.index("SpineBase"), 0]
    past = np.flatnonzero(pelvis_x >= WALK_FROM[0] + WALK_M)
    return w, float(t[past[0]]) if len(past) else 10.0


def _paper_analysis() -> GaitAnalysis:
    """The paper's gait analysis: placement at the crossing instant, fixed walkway axis,
    its exclusion rule taken literally (first left step, first right stride), crossings
    only between consecutive samples (its data's gaps were filled up to 0.2 s only)."""
    return GaitAnalysis("crossing", exclude_first="L", placement_window_s=0.0,
                        direction=PAPER_AXIS, max_crossing_gap_s=0.0)


def _our_analysis() -> GaitAnalysis:
    """Ours: stance estimate of each placement, direction from the footprints."""
    return GaitAnalysis("crossing", exclude_first=True)


def _reference(w: Walker, t_end: float, paper: bool) -> GaitAnalysis:
    """The reference ("Vicon") analysis of the true joints at 100 Hz, in the lab frame."""
    t = np.arange(0.0, t_end, 0.01)
    J = w.joints(t)
    s = SkeletonSeries(t, J, np.full(J.shape[:2], TrackingState.TRACKED, np.uint8), KINECT_V2)
    ga = _paper_analysis() if paper else GaitAnalysis("crossing", exclude_first=True,
                                                      placement_window_s=0.0)
    return ga.fit(feet_from_skeleton(s))


def _yaw(deg: float) -> NDArray[np.float64]:
    a = np.radians(deg)
    R = np.eye(4)
    R[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    return R


def _observe(w: Walker, t_end: float, rig: Any, rng: np.random.Generator,
             model: SkeletonErrorModel | None = None, shared_seed: int | None = None
             ) -> list[SensorStream]:
    out = []
    # The Kinect side's world frame is the reference lab frame rotated by the
    # registration yaw: its calibrated sensor poses place everything rotated.
    R = _yaw(REGISTRATION_YAW_DEG)
    for s in rig.sensors:
        times = frame_times(0.0, t_end, rng)
        ser = observe_skeletons(s, rig, w, times, rng, model, shared_seed=shared_seed)
        out.append(SensorStream(ser, R @ s.T_world_sensor, s.clock_offset_s,
                                s.clock_drift_ppm, s.id))
    return out


def _row(a: Any, scale: float) -> dict[str, Any]:
    return {"n": a.n, "bias": round(a.bias * scale, 2), "rpc": round(a.rpc * scale, 2),
            "icc": round(a.icc_a1, 3), "r": round(a.r, 3),
            "ref_mean_sd": [round(a.mean_reference * scale, 2),
                            round(a.sd_reference * scale, 2)]}


BAND_ROWS = [f"{p} {s}" for p in ("step_length", "step_width") for s in "LR"]


def _band(res: dict[str, Any]) -> dict[str, Any]:
    """Realism band: paper's-method step rows (``res["one_sided_mean"]`` etc., each with
    ``icc`` and ``bias``) against Tables 2–3."""
    band: dict[str, Any] = {}
    for side in ("one", "two"):
        for row in BAND_ROWS:
            icc_p, bias_p = PAPER[side][row]
            sim = res[f"{side}_sided_mean"].get(row)
            if sim:
                band[f"{side}-sided {row}"] = {
                    "icc": sim["icc"], "bias_cm": sim["bias"],
                    "d_icc": round(sim["icc"] - icc_p, 3),
                    "d_bias_cm": round(sim["bias"] - bias_p, 2),
                    "within": abs(sim["icc"] - icc_p) <= 0.1 and abs(sim["bias"] - bias_p) <= 1.0}
    return band


def _within(band: dict[str, Any]) -> str:
    return f"{sum(b['within'] for b in band.values())}/{len(band)}"


def _study(n_subjects: int, n_walks: int, seed: int,
           model: SkeletonErrorModel | None = None,
           paper_kept_states: tuple[int, ...] = PAPER_KEPT_STATES) -> dict[str, Any]:
    """One simulated study (one sample of subjects, walks and sensor errors);
    ``paper_kept_states``: the tracking states the paper's mean keeps (ours always keeps
    TRACKED only)."""
    rng = np.random.default_rng(seed)
    rig = default_avenue_rig(seed=seed)
    configs = [(side, est) for side in ("one", "two") for est in ("mean", "weighted")]
    trials: dict[tuple[str, str], dict[str, list[tuple[list[Step], list[Step]]]]] = {
        c: {} for c in configs}
    strides: dict[tuple[str, str], dict[str, list[tuple[list[Stride], list[Stride]]]]] = {
        c: {} for c in configs}
    speed: dict[tuple[str, str], tuple[list[float], list[float]]] = {c: ([], []) for c in configs}
    failures: dict[str, int] = {}
    for subj in range(n_subjects):
        params = WalkerParams.random(rng)
        sid = f"P{subj + 1:02d}"
        subj_speed: dict[tuple[str, str], tuple[list[float], list[float]]] = {
            c: ([], []) for c in configs}
        for walk in range(n_walks):
            w, t_end = _walk(params, seed=1000 * subj + walk)
            refs = {"mean": _reference(w, t_end, True), "weighted": _reference(w, t_end, False)}
            # errors with a common cause (shared by the sensors of one walk) draw from
            # a seed of their own, so that the study's other draws are unchanged
            streams = _observe(w, t_end, rig, rng, model,
                               shared_seed=int(np.random.default_rng(
                                   [seed, subj, walk, 7]).integers(2**31)))
            for side, est in configs:
                use = streams if side == "two" else [s for s in streams
                                                     if s.sensor_id in ONE_SIDED]
                try:
                    kept = paper_kept_states if est == "mean" else PAPER_KEPT_STATES
                    fused, _ = integrate_skeletons(use, est,  # type: ignore[arg-type]
                                                   kept_states=kept)
                    # every walk starts from standing: the paper's exclusion rule applies
                    # "mean" is the paper's method throughout (placement at the crossing
                    # instant); "weighted" is ours (plus the stance median of placements).
                    ga = _paper_analysis() if est == "mean" else _our_analysis()
                    g = ga.fit(feet_from_skeleton(fused))
                except GaitrigError as exc:
                    key = type(exc).__name__
                    failures[key] = failures.get(key, 0) + 1
                    continue
                ref = refs[est]
                trials[(side, est)].setdefault(sid, []).append((g.steps_, ref.steps_))
                strides[(side, est)].setdefault(sid, []).append((g.strides_, ref.strides_))
                subj_speed[(side, est)][0].append(g.summary_["walking_speed_m_s"])
                subj_speed[(side, est)][1].append(ref.summary_["walking_speed_m_s"])
        for c in configs:
            if subj_speed[c][0]:
                speed[c][0].append(float(np.mean(subj_speed[c][0])))
                speed[c][1].append(float(np.mean(subj_speed[c][1])))

    out: dict[str, Any] = {"seed": seed, "failed_walks": failures}
    for side, est in configs:
        res: dict[str, Any] = {}
        for attr, name, scale, data in (("length_m", "step_length", 100.0, trials),
                                        ("width_m", "step_width", 100.0, trials),
                                        ("duration_s", "step_time", 1.0, trials),
                                        ("length_m", "stride_length", 100.0, strides)):
            lv = agreement_levels(data[(side, est)], attr)  # type: ignore[arg-type]
            for k, a in lv.items():
                res[f"{name} {k}"] = _row(a, scale)
        if len(speed[(side, est)][0]) >= 3:
            res["AV walking_speed"] = _row(agreement(*speed[(side, est)]), 100.0)
        out[f"{side}_sided_{est}"] = res
    # Realism band of issue 8 (paper's method vs Tables 2-3: ICC within ±0.1, bias within
    # ±1 cm at step level) and the acceptance of our estimator (two-sided, step level:
    # ICC(A,1) ≥ 0.90 for step length, width and time; |step-width bias| ≤ 0.5 cm).
    out["realism_band"] = _band(out)
    out["realism_within"] = _within(out["realism_band"])
    two, one = out["two_sided_mean"], out["one_sided_mean"]
    out["one_sided_worse"] = all(one[r]["icc"] < two[r]["icc"] for r in
                                 ("step_length L", "step_length R", "step_width L",
                                  "step_width R") if r in one and r in two)
    ow, tw = out["one_sided_weighted"], out["two_sided_weighted"]
    out["ours_one_sided_worse"] = all(ow[r]["icc"] < tw[r]["icc"] for r in
                                      ("step_length L", "step_length R", "step_width L",
                                       "step_width R") if r in ow and r in tw)
    ours = out["two_sided_weighted"]
    rows = [f"{p} {s}" for p in ("step_length", "step_width", "step_time") for s in "LR"]
    out["ours_acceptance"] = {
        "min_step_icc": min(ours[r]["icc"] for r in rows if r in ours),
        "max_abs_step_width_bias_cm": max(abs(ours[r]["bias"]) for r in rows[2:4] if r in ours),
    }
    out["ours_acceptance"]["met"] = (out["ours_acceptance"]["min_step_icc"] >= 0.90
                                     and out["ours_acceptance"]["max_abs_step_width_bias_cm"]
                                     <= 0.5)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--subjects", type=int, default=10)
    ap.add_argument("--walks", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0, help="first seed")
    ap.add_argument("--model", default="{}",
                    help="JSON object of SkeletonErrorModel overrides (default: the "
                         "model's defaults), e.g. '{\"far_leg_refit_sd_m\": 0.02}'")
    ap.add_argument("--seeds", type=int, default=5,
                    help="number of studies (seeds seed, seed+1, ...); the realism band is "
                         "judged on the mean over them of each row's ICC and bias")
    ap.add_argument("--paper-keeps-inferred", action="store_true",
                    help="the paper's mean keeps INFERRED joints and drops only "
                         "NOT_TRACKED ones (its Discussion's reading; default: its "
                         "Methods', TRACKED only); ours is unchanged")
    args = ap.parse_args()
    t_start = time.perf_counter()
    seeds = list(range(args.seed, args.seed + max(args.seeds, 1)))
    overrides = json.loads(args.model)
    if not isinstance(overrides, dict):
        ap.error("--model must be a JSON object")
    model = SkeletonErrorModel(**overrides)
    kept = PAPER_KEPT_STATES_DISCUSSION if args.paper_keeps_inferred else PAPER_KEPT_STATES
    runs = [_study(args.subjects, args.walks, sd, model, kept) for sd in seeds]
    first = runs[0]
    out: dict[str, Any] = {"bench": "gait_study", "subjects": args.subjects,
                           "walks": args.walks, "seeds": seeds, "model": overrides,
                           "paper_kept_states": [TrackingState(k).name for k in kept]}
    # Detailed rows of the first seed's study (one sample, as the paper's).
    out["first_seed"] = first
    # The reported realism figure: per row, the mean over the seeds' studies of the
    # paper's-method ICC(A,1) and bias, so that the band is not one sample's luck (one
    # sample of ten subjects moves a row's ICC by up to ±0.2).
    mean_rows: dict[str, Any] = {}
    for side in ("one", "two"):
        key = f"{side}_sided_mean"
        mean_rows[key] = {
            r: {"icc": round(float(np.mean([x[key][r]["icc"] for x in runs])), 3),
                "bias": round(float(np.mean([x[key][r]["bias"] for x in runs])), 2),
                "icc_range": [min(x[key][r]["icc"] for x in runs),
                              max(x[key][r]["icc"] for x in runs)]}
            for r in BAND_ROWS if all(r in x[key] for x in runs)}
    out["realism_figure"] = (f"mean over seeds {seeds[0]}..{seeds[-1]} of each row's "
                             "step-level ICC(A,1) and bias (paper's averaging)")
    out["realism_rows"] = mean_rows
    out["realism_band"] = _band(mean_rows)
    out["realism_within"] = _within(out["realism_band"])
    out["realism_within_per_seed"] = {str(x["seed"]): x["realism_within"] for x in runs}
    out["one_sided_worse"] = all(
        mean_rows["one_sided_mean"][r]["icc"] < mean_rows["two_sided_mean"][r]["icc"]
        for r in BAND_ROWS if r in mean_rows["one_sided_mean"]
        and r in mean_rows["two_sided_mean"])
    # Our estimator's acceptance on the same footing (mean over the seeds of each row),
    # and each seed's own figures.
    ours_rows = [f"{p} {s}" for p in ("step_length", "step_width", "step_time") for s in "LR"]
    tw_mean = {r: {k: float(np.mean([x["two_sided_weighted"][r][k] for x in runs]))
                   for k in ("icc", "bias")}
               for r in ours_rows if all(r in x["two_sided_weighted"] for x in runs)}
    out["ours_acceptance"] = {
        "scope": "mean over the seeds of each two-sided step row (ours)",
        "min_step_icc": round(min(v["icc"] for v in tw_mean.values()), 3),
        "max_abs_step_width_bias_cm": round(max(abs(tw_mean[r]["bias"]) for r in
                                                ours_rows[2:4] if r in tw_mean), 2)}
    out["ours_acceptance"]["met"] = (out["ours_acceptance"]["min_step_icc"] >= 0.90
                                     and out["ours_acceptance"]["max_abs_step_width_bias_cm"]
                                     <= 0.5)
    out["ours_acceptance_per_seed"] = {str(x["seed"]): x["ours_acceptance"] for x in runs}
    out["ours_one_sided_worse_per_seed"] = {str(x["seed"]): x["ours_one_sided_worse"]
                                            for x in runs}
    out["paper"] = {"one_sided_step_level": PAPER["one"], "two_sided_step_level": PAPER["two"],
                    "step_time": PAPER["step_time"], "units": "(ICC(A,1), bias cm)"}
    out["elapsed_s"] = round(time.perf_counter() - t_start, 1)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
