"""Seed 004's Table I in simulation: two sensors calibrate one person with KSCC.

One standing person (``engine.sim.walker``, 1.75 m) is seen by two level Kinect-v2-like
sensors 1 m high and 2.5 m away (``engine.sim.skeleton_model``: distance-scaled noise,
slowly varying fitting error, a bias towards the visible surface that is larger for the
body half turned away, self-occlusion → INFERRED joints with larger errors, NOT_TRACKED
when the occlusion lasts — so a far shoulder hidden behind the body is lost). The two
sensors sit at the paper's pairs of initial angles (Table I) and at symmetric pairs
beyond. Each sensor's stream is calibrated independently with KSCC (120 still frames
found by the stillness detector); then the person stands at seven locations (initial,
one step forward, left, right, back, back-left, back-right; 0.5 m steps) and the two
calibrated shoulder positions are compared — average |difference| per axis in the
paper's axes (X lateral, Y vertical, Z depth); one recording is the 1 s (30 frame) mean
of a shoulder at a location; averaged over both shoulders, the locations and ``REPS``
random repetitions. Same criterion as the paper: every axis ≤ 4 cm.

Two variants are run in the same pass: ``paper`` (facing from the shoulders, every joint
the SDK reports, as in the seed) and ``trunk`` (facing from the shoulder and hip lines,
falling back to half lines when the far shoulder is hidden — see
``engine.kscc.facing_left``). A recording where one sensor does not track a shoulder is
left out and counted as missing (the paper only tested poses where all joints were
detected).
Prints one JSON line (the table included) and a readable table on stderr.
"""

from __future__ import annotations

import json
import sys
from typing import Any, cast

import numpy as np

from engine.errors import GaitrigError
from engine.kscc import FacingMode, KsccCalibrator
from engine.sim.rig import SimSensor, sensor_pose
from engine.sim.skeleton_model import observe_skeletons
from engine.sim.walker import Walker, WalkerParams
from engine.skeleton import SkeletonSeries

FPS = 30.0
DIST_M = 2.5
STEP_M = 0.5
N_CAL = 300  # frames standing at the start: acquisition delay + 120 still frames + a restart
N_LOC_TOTAL = 75  # frames at each location (the body is acquired again after a step) …
N_LOC = 30  # … of which the last 30 (1 s) make one recording
VARIANTS: dict[str, FacingMode] = {"paper": "shoulders", "trunk": "trunk"}
#: the seven locations of the paper (person faces +X; +Y is the person's left)
LOCATIONS = {"initial": (0, 0), "forward": (1, 0), "left": (0, 1), "right": (0, -1),
             "back": (-1, 0), "back-left": (-1, 1), "back-right": (-1, -1)}
#: Table I of seed 004: (left angle, right angle, avg |Δ| after movement X, Y, Z in cm)
PAPER = [
    (-3.4648, 0.7889, (2.00, 1.28, 3.78)), (16.3570, 0.5013, (1.71, 1.57, 2.92)),
    (21.2544, 0.1923, (1.21, 1.50, 2.14)), (26.4897, 0.9105, (1.85, 1.92, 3.87)),
    (14.9705, -12.1837, (2.14, 1.50, 1.64)), (30.6423, 2.0577, (4.50, 1.50, 5.57)),
    (21.0891, -17.7214, (2.00, 1.78, 3.21)), (24.5130, -19.8589, (4.28, 1.64, 5.28)),
    (24.5566, -25.8503, (6.35, 2.21, 6.00)), (29.3320, -26.0919, (4.50, 3.21, 5.71)),
]
EXTRA = [(a, -a) for a in (10.0, 20.0, 30.0, 35.0, 40.0, 45.0, 50.0, 60.0)]
LIMIT_CM = 4.0
REPS = 6


def _sensor(sid: str, angle_deg: float) -> SimSensor:
    """A level sensor whose view of the +X-facing person has the paper's initial angle.

    Facing the sensor is 0°; a sensor towards the person's left (CCW) sees the left
    shoulder nearer, which the paper calls a positive angle.
    """
    a = np.radians(angle_deg)
    pos = np.array([DIST_M * np.cos(a), DIST_M * np.sin(a), 1.0])
    return SimSensor(sid, sensor_pose(pos, np.degrees(a) + 180.0, 0.0))


class _Standing:
    """A person standing still at ``(x, y)`` facing +X, with a slow postural sway.

    The pose is the simulated walker's (``engine.sim.walker``) at the instant it starts
    from standing; the walker itself is not held still before/after its walk, so the
    pose is frozen here and moved rigidly. Offers the three methods
    ``observe_skeletons`` uses (joints, capsule_segments, bone_frames).
    """

    _walker = Walker(WalkerParams(), [0.0, 0.0, 0.0], [10.0, 0.0, 0.0], start_time=0.0,
                     back_and_forth=False, horizon_s=1.0)

    def __init__(self, x: float, y: float, sway_m: float = 0.004) -> None:
        self.offset = np.array([x, y, 0.0])
        self.sway_m = sway_m

    def _shift(self, t: np.ndarray) -> np.ndarray:
        # ~0.2–0.3 Hz postural sway of a few mm (standing balance), same for every joint
        t = np.asarray(t, dtype=float)
        sway = self.sway_m * np.stack([np.sin(2 * np.pi * 0.23 * t),
                                       np.sin(2 * np.pi * 0.31 * t + 1.0), 0 * t], 1)
        return self.offset + sway

    def joints(self, t: np.ndarray) -> np.ndarray:
        J0 = self._walker.joints(np.array([0.0]))[0]
        return J0[None] + self._shift(t)[:, None]

    def capsule_segments(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        A, B, r = self._walker.capsule_segments(np.array([0.0]))
        d = self._shift(t)[:, None]
        return A + d, B + d, r

    def bone_frames(self, t: np.ndarray) -> dict[str, np.ndarray]:
        fr = self._walker.bone_frames(np.array([0.0]))
        d = self._shift(t)
        out = {}
        for k, F in fr.items():
            G = np.repeat(F, len(d), axis=0)
            G[:, :3, 3] += d
            out[k] = G
        return out


def _walker(x: float, y: float) -> Walker:
    return cast(Walker, _Standing(x, y))


def _observe(sensor: SimSensor, walker: Walker, t: np.ndarray, rng: np.random.Generator
             ) -> SkeletonSeries:
    return observe_skeletons(sensor, None, walker, t, rng)


def run_pair(left_deg: float, right_deg: float, rng: np.random.Generator
             ) -> dict[str, Any]:
    """One repetition: calibrate both sensors, then compare at the seven locations."""
    sensors = [_sensor("L", left_deg), _sensor("R", right_deg)]
    t_cal = np.arange(N_CAL) / FPS
    home = _walker(0.0, 0.0)
    obs_cal = [_observe(s, home, t_cal, rng) for s in sensors]
    out: dict[str, Any] = {}
    for name, facing in VARIANTS.items():
        try:
            cal = [KsccCalibrator(frame="opencv", facing=facing).fit(o) for o in obs_cal]
        except GaitrigError as e:  # e.g. the far shoulder hidden behind the body
            out[name] = {"failed": str(e).split(";")[0]}
            continue
        per: dict[str, np.ndarray] = {}
        t = (N_CAL + 30 + np.arange(N_LOC_TOTAL)) / FPS
        for loc, (fx, fy) in LOCATIONS.items():
            w = home if loc == "initial" else _walker(fx * STEP_M, fy * STEP_M)
            obs = [_observe(s, w, t, rng) for s in sensors]
            js = obs[0].joint_set
            idx = [js.role_index("shoulder_left"), js.role_index("shoulder_right")]
            u = [c.transform_points(o.tracked_positions()[-N_LOC:, idx])
                 for c, o in zip(cal, obs, strict=True)]
            # one "recording" = the 1 s mean of each shoulder; universal (X fwd, Y left,
            # Z up) → paper axes (X lateral, Y vertical, Z depth)
            d = np.abs(_nanmean(u[0], 0) - _nanmean(u[1], 0))
            per[loc] = 100.0 * d[:, [1, 2, 0]]
        allp = np.stack(list(per.values()))  # (7 locations, 2 shoulders, 3)
        out[name] = {
            "angles_deg": [round(float(c.initial_angle_deg_ or 0.0), 2) for c in cal],
            "before_cm": _nanmean(per["initial"], 0),
            "after_cm": _nanmean(allp.reshape(-1, 3), 0),
            # recordings (of 14) where a shoulder was not tracked by one of the sensors
            "missing": float(np.isnan(allp).any(axis=-1).sum()),
        }
    return out


def _nanmean(a: np.ndarray, axis: int) -> np.ndarray:
    """Mean ignoring NaN; NaN where every value is missing (a hidden shoulder)."""
    ok = np.isfinite(a)
    n = ok.sum(axis)
    return np.where(n > 0, np.where(ok, a, 0.0).sum(axis) / np.maximum(n, 1), np.nan)


def main() -> None:
    reps = REPS
    rows = []
    for left, right, paper_after in [(a, b, p) for a, b, p in PAPER] + [
            (a, b, None) for a, b in EXTRA]:
        res = [run_pair(left, right, np.random.default_rng(
            [i, int(1000 + 10 * left), int(1000 + 10 * right)])) for i in range(reps)]
        row: dict[str, Any] = {"left_deg": left, "right_deg": right,
                               "gap_deg": round(abs(left - right), 2),
                               "paper_after_cm": paper_after}
        for name in VARIANTS:
            good = [r[name] for r in res if "failed" not in r[name]]
            if len(good) < len(res):
                row[name] = {"failed": next(r[name]["failed"] for r in res
                                            if "failed" in r[name]),
                             "failed_reps": len(res) - len(good)}
                continue
            row[name] = {k: [round(float(v), 2)
                             for v in _nanmean(np.array([g[k] for g in good]), 0)]
                         for k in ("angles_deg", "before_cm", "after_cm")}
            row[name]["missing_of_14"] = round(float(np.mean([g["missing"] for g in good])), 1)
        rows.append(row)

    def ok(r: dict[str, Any], name: str) -> bool:
        v = r[name]
        return ("failed" not in v and v["missing_of_14"] < 7
                and max(v["after_cm"]) <= LIMIT_CM)

    def reach(name: str, cond: Any) -> float:
        """Largest |angle| of the symmetric pairs up to which every pair meets ``cond``."""
        best = 0.0
        for r in rows[len(PAPER):]:
            if not cond(r, name):
                break
            best = abs(r["left_deg"])
        return best

    paper_rows_le20 = [r for r in rows[:len(PAPER)]
                       if max(abs(r["left_deg"]), abs(r["right_deg"])) <= 21.3]
    summary: dict[str, Any] = {
        "bench": "kscc",
        "reps": reps,
        "sensor_distance_m": DIST_M,
        "step_m": STEP_M,
        "rows": rows,
        "paper_claim": "avg difference ≤ 4 cm when both initial angles ≤ ~20°",
        "reproduced_le20deg": all(ok(r, "paper") for r in paper_rows_le20),
        "max_after_cm_le20deg": max(max(r["paper"].get("after_cm", [np.inf]))
                                    for r in paper_rows_le20),
    }
    for name in VARIANTS:
        summary[f"{name}_symmetric_calibrates_up_to_deg"] = reach(
            name, lambda r, n: "failed" not in r[n])
        summary[f"{name}_symmetric_within_4cm_up_to_deg"] = reach(name, ok)
    print(json.dumps(summary))
    err = sys.stderr

    def fmt(r: dict[str, Any], name: str, key: str) -> str:
        v = r[name]
        if "failed" in v:
            return "failed"
        miss = (f" ({v['missing_of_14']:.0f} miss)"
                if key == "after_cm" and v["missing_of_14"] else "")
        return "/".join(f"{x:.1f}" for x in v[key]) + miss

    print(f"{'L°':>8}{'R°':>8}{'gap°':>7} | {'Table I after X/Y/Z cm':>22} | "
          f"{'sim before X/Y/Z':>16} | {'sim after X/Y/Z':>24} | {'trunk after X/Y/Z':>24}",
          file=err)
    for r in rows:
        pa = "/".join(f"{v:.1f}" for v in r["paper_after_cm"]) if r["paper_after_cm"] else "—"
        print(f"{r['left_deg']:>8.1f}{r['right_deg']:>8.1f}{r['gap_deg']:>7.1f} | {pa:>22} | "
              f"{fmt(r, 'paper', 'before_cm'):>16} | {fmt(r, 'paper', 'after_cm'):>24} | "
              f"{fmt(r, 'trunk', 'after_cm'):>24}", file=err)
    for name in VARIANTS:
        print(f"{name}: symmetric pairs calibrate up to "
              f"±{summary[f'{name}_symmetric_calibrates_up_to_deg']}°, stay ≤ {LIMIT_CM} cm up "
              f"to ±{summary[f'{name}_symmetric_within_4cm_up_to_deg']}°", file=err)


if __name__ == "__main__":
    main()
