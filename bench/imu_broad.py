"""BROAD orientation benchmark: our Madgwick and our filter vs ``ahrs`` and ``vqf``.

``ours_best_*`` is our causal filter against causal VQF (``vqf.VQF``); the offline keys
compare our two-pass mode with ``vqf.offlineVQF``.

Usage: ``python bench/imu_broad.py [PATH ...]`` — BROAD trial files (.hdf5/.mat) or
folders of them; default ``../shared/data/imu/broad``. Prints ONE JSON line: mean over the
trials of the BROAD error measure (9D total RMSE, 6D inclination RMSE, degrees), and
throughput in samples per second with ratios against the peers measured in the same run.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
# Running "python bench/x.py" puts bench/ first on sys.path, where a bench script could
# shadow an installed package of the same name; import from the project root instead.
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != ROOT / "bench"]
sys.path.insert(0, str(ROOT))

from engine.imu.filter import orientation_filter  # noqa: E402
from engine.imu.io import ImuRecording, load_broad  # noqa: E402
from engine.imu.madgwick import initial_orientation, madgwick, to_enu  # noqa: E402
from engine.imu.metrics import orientation_errors  # noqa: E402

BETA = 0.12  # BROAD paper's Madgwick gain


def _trial_files(args: list[str]) -> list[Path]:
    paths = [Path(a) for a in args] or [ROOT.parent / "shared" / "data" / "imu" / "broad"]
    files: list[Path] = []
    for p in paths:
        if p.is_dir():
            files += sorted(x for x in p.iterdir() if x.suffix.lower() in (".hdf5", ".h5", ".mat"))
        elif p.is_file():
            files.append(p)
        else:
            raise SystemExit(f"no such trial file or folder: {p}")
    if not files:
        raise SystemExit("no BROAD trials found")
    return files


def _timed(fn, *a, **k):  # type: ignore[no-untyped-def]
    t0 = time.perf_counter()
    out = fn(*a, **k)
    return out, time.perf_counter() - t0


def main(argv: list[str]) -> int:
    import vqf
    from ahrs.filters import Madgwick as AhrsMadgwick

    files = _trial_files(argv)
    recs: list[ImuRecording] = [load_broad(f) for f in files]
    # compile once outside the timing
    r0 = recs[0]
    assert r0.mag is not None
    madgwick(r0.gyr[:10], r0.acc[:10], r0.mag[:10], beta=BETA, frequency=r0.frequency)
    orientation_filter(r0.gyr[:10], r0.acc[:10], r0.mag[:10], frequency=r0.frequency)
    orientation_filter(r0.gyr[:10], r0.acc[:10], None, frequency=r0.frequency)
    orientation_filter(r0.gyr[:100], r0.acc[:100], r0.mag[:100], frequency=r0.frequency,
                       offline=True)

    res: dict[str, list[float]] = {k: [] for k in (
        "ours_madgwick_total", "ahrs_madgwick_total", "ours_best_total", "ours_best_incl",
        "vqf_total", "vqf_incl", "madgwick_max_abs_diff_deg", "ours_offline_total",
        "ours_offline_incl", "vqf_offline_total", "vqf_offline_incl")}
    secs = {"ours_madgwick": 0.0, "ours_best": 0.0, "ahrs": 0.0, "vqf": 0.0,
            "ours_offline": 0.0}
    n_total = 0
    for r in recs:
        assert r.mag is not None and r.quat_ref is not None and r.movement is not None
        g, a, m, fs = r.gyr, r.acc, r.mag, r.frequency
        n_total += len(g)
        # Same initial state for both Madgwick implementations: ENU TRIAD from sample 0.
        q0 = initial_orientation(a[0], m[0], "NWU")
        qm, dt = _timed(madgwick, g, a, m, beta=BETA, frequency=fs, q0=q0)
        secs["ours_madgwick"] += dt
        ahrs_run, dt = _timed(AhrsMadgwick, gyr=g, acc=a, mag=m, frequency=fs, gain=BETA)
        qa = ahrs_run.Q
        secs["ahrs"] += dt
        # ahrs ignores q0 in MARG mode (starts from its own e-compass); rerun ours from its
        # start so that the two are compared on the same initial state.
        qm_same = madgwick(g, a, m, beta=BETA, frequency=fs, q0=qa[0])
        res["madgwick_max_abs_diff_deg"].append(
            orientation_errors(to_enu(qm_same), to_enu(qa))["total_deg"])
        q9, dt9 = _timed(orientation_filter, g, a, m, frequency=fs)
        q6, dt6 = _timed(orientation_filter, g, a, None, frequency=fs)
        secs["ours_best"] += dt9 + dt6
        v = vqf.VQF(1.0 / fs)
        vo, dt = _timed(v.updateBatch, np.ascontiguousarray(g), np.ascontiguousarray(a),
                        np.ascontiguousarray(m))
        v6 = vqf.VQF(1.0 / fs)
        vo6, dt6v = _timed(v6.updateBatch, np.ascontiguousarray(g), np.ascontiguousarray(a))
        secs["vqf"] += dt + dt6v
        ref, mov = r.quat_ref, r.movement
        res["ours_madgwick_total"].append(orientation_errors(to_enu(qm), ref, mov)["total_deg"])
        res["ahrs_madgwick_total"].append(orientation_errors(to_enu(qa), ref, mov)["total_deg"])
        res["ours_best_total"].append(orientation_errors(q9[0], ref, mov)["total_deg"])
        res["ours_best_incl"].append(orientation_errors(q6[0], ref, mov)["inclination_deg"])
        res["vqf_total"].append(orientation_errors(vo["quat9D"], ref, mov)["total_deg"])
        res["vqf_incl"].append(orientation_errors(vo6["quat6D"], ref, mov)["inclination_deg"])
        # offline (non-causal) variants, compared with VQF's own offline version
        (q9o, _, _), dto9 = _timed(orientation_filter, g, a, m, frequency=fs, offline=True)
        (q6o, _, _), dto6 = _timed(orientation_filter, g, a, None, frequency=fs, offline=True)
        secs["ours_offline"] += dto9 + dto6
        gc, ac, mc = (np.ascontiguousarray(x) for x in (g, a, m))
        vo9o = vqf.offlineVQF(gc, ac, mc, 1.0 / fs)
        vo6o = vqf.offlineVQF(gc, ac, None, 1.0 / fs)
        res["ours_offline_total"].append(orientation_errors(q9o, ref, mov)["total_deg"])
        res["ours_offline_incl"].append(orientation_errors(q6o, ref, mov)["inclination_deg"])
        res["vqf_offline_total"].append(orientation_errors(vo9o["quat9D"], ref, mov)["total_deg"])
        res["vqf_offline_incl"].append(
            orientation_errors(vo6o["quat6D"], ref, mov)["inclination_deg"])

    sps = {k: (n_total * (2 if k in ("ours_best", "vqf", "ours_offline") else 1)) / v
           for k, v in secs.items()}
    out = {
        "trials": len(recs),
        "samples": n_total,
        "ours_madgwick_total_deg": round(float(np.mean(res["ours_madgwick_total"])), 3),
        "ahrs_madgwick_total_deg": round(float(np.mean(res["ahrs_madgwick_total"])), 3),
        "madgwick_same_init_worst_trial_rms_diff_deg": round(
            float(np.max(res["madgwick_max_abs_diff_deg"])), 6),
        "ours_best_total_deg": round(float(np.mean(res["ours_best_total"])), 3),
        "ours_best_incl_deg": round(float(np.mean(res["ours_best_incl"])), 3),
        "vqf_total_deg": round(float(np.mean(res["vqf_total"])), 3),
        "vqf_incl_deg": round(float(np.mean(res["vqf_incl"])), 3),
        "ours_offline_total_deg": round(float(np.mean(res["ours_offline_total"])), 3),
        "ours_offline_incl_deg": round(float(np.mean(res["ours_offline_incl"])), 3),
        "vqf_offline_total_deg": round(float(np.mean(res["vqf_offline_total"])), 3),
        "vqf_offline_incl_deg": round(float(np.mean(res["vqf_offline_incl"])), 3),
        "ours_samples_per_s": round(min(sps["ours_madgwick"], sps["ours_best"])),
        "ours_madgwick_samples_per_s": round(sps["ours_madgwick"]),
        "ours_best_samples_per_s": round(sps["ours_best"]),
        "ours_offline_samples_per_s": round(sps["ours_offline"]),
        "ahrs_samples_per_s": round(sps["ahrs"]),
        "vqf_samples_per_s": round(sps["vqf"]),
        "ours_madgwick_vs_ahrs_speed": round(sps["ours_madgwick"] / sps["ahrs"], 1),
        "ours_best_vs_vqf_speed": round(sps["ours_best"] / sps["vqf"], 2),
        "ours_best_vs_vqf_total_ratio": round(float(np.mean(res["ours_best_total"])
                                                    / np.mean(res["vqf_total"])), 3),
        "ours_best_vs_vqf_incl_ratio": round(float(np.mean(res["ours_best_incl"])
                                                   / np.mean(res["vqf_incl"])), 3),
        "per_trial": {
            r.name: {k: round(v[i], 3) for k, v in res.items()} for i, r in enumerate(recs)},
    }
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
