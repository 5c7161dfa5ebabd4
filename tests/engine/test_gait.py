"""Gait engine against synthetic walks with exact ground truth."""

from __future__ import annotations

import json

import numpy as np
import pytest

from engine import gait
from engine.errors import InputError, InsufficientDataError
from engine.gait import GaitAnalysis
from engine.io.markers import MarkerTrajectories
from engine.mocap import FeetTrajectories, feet_from_markers
from engine.sim.straight_walk import synth_walk, walk_markers


@pytest.mark.parametrize("heading", [0.0, 37.0, 200.0])
def test_crossing_recovers_steps_far_from_origin(heading: float) -> None:
    w = synth_walk(step_length=0.68, step_width=0.14, step_time=0.56,
                   origin=(1200.0, -830.0, 4.0), heading_deg=heading)
    g = GaitAnalysis("crossing").fit(feet_from_markers(walk_markers(w)))
    assert len(g.passes_) == 1
    d = np.array(g.passes_[0].direction)
    assert np.degrees(np.arccos(np.clip(d @ [np.cos(np.radians(heading)),
                                             np.sin(np.radians(heading))], -1, 1))) < 1.0
    assert len(g.steps_) >= 7
    for s in g.steps_:
        assert s.length_m == pytest.approx(0.68, abs=0.002)
        assert s.width_m == pytest.approx(0.14, abs=0.002)
        assert s.duration_s == pytest.approx(0.56, abs=0.011)
    assert {s.side for s in g.steps_} == {"L", "R"}
    for s in g.strides_:
        assert s.length_m == pytest.approx(1.36, abs=0.003)
    assert g.summary_["walking_speed_m_s"] == pytest.approx(0.68 / 0.56, rel=0.01)
    assert g.summary_["cadence_steps_min"] == pytest.approx(60 / 0.56, rel=0.01)
    assert g.summary_["stance_pct"] is None  # crossings give no foot-off


def test_heelstrike_events_match_truth() -> None:
    w = synth_walk(step_length=0.7, step_width=0.1, step_time=0.55, rate=100.0)
    g = GaitAnalysis("heelstrike").fit(feet_from_markers(walk_markers(w)))
    fs = [e for e in g.events_ if e.kind == "foot_strike"]
    truth = [(s, t) for s, t, _ in w.strikes]
    assert len(fs) >= len(truth) - 1  # the strike at t = 0 has no peak before it
    for e in fs:
        side, tt = min(truth, key=lambda x: abs(x[1] - e.time_s))
        assert side == e.side
        assert abs(tt - e.time_s) <= 0.005  # half a frame at 100 Hz
    for s in g.steps_:
        assert s.length_m == pytest.approx(0.7, abs=0.01)
        assert s.width_m == pytest.approx(0.1, abs=0.005)
    fo = [e for e in g.events_ if e.kind == "foot_off"]
    assert len(fo) >= len(w.offs) - 1
    for e in fo:
        side, tt = min(w.offs, key=lambda x: abs(x[1] - e.time_s))
        # the synthetic toe's velocity jumps at lift-off: up to 1.5 frames off
        assert side == e.side and abs(tt - e.time_s) <= 0.016
    # stance = (step + double support) / stride = 0.65 / 1.1; double support 2 × 0.1 / 1.1
    assert g.summary_["stance_pct"]["mean"] == pytest.approx(100 * 0.65 / 1.1, abs=1.5)
    # the foot offs may each be up to 15 ms late (above), which lengthens each of the two
    # double-support phases: up to 2 × 15 ms / 1.1 s = 2.7 % of the cycle
    assert g.summary_["double_support_pct"]["mean"] == pytest.approx(100 * 0.2 / 1.1, abs=3.0)


def test_asymmetry_and_variability() -> None:
    w = synth_walk(step_width=0.1, side_bias=0.04)  # right foot placed 4 cm further out
    g = GaitAnalysis("crossing").fit(feet_from_markers(walk_markers(w)))
    sw = g.summary_["step_width_m"]
    assert sw["left_mean"] == pytest.approx(0.14, abs=0.003)
    assert sw["right_mean"] == pytest.approx(0.14, abs=0.003)
    assert sw["cv_pct"] < 3.0
    sl = g.summary_["step_length_m"]
    assert sl["asymmetry_pct"] < 1.0


def test_back_and_forth_passes_and_turns() -> None:
    a = synth_walk(n_steps=9)
    b = synth_walk(n_steps=9, origin=(a.joints["pelvis"][-1, 0] + 0.4, 0.3, 0.0),
                   heading_deg=180.0)
    m1, m2 = walk_markers(a), walk_markers(b)
    # stand still 1.5 s between the passes (turning on the spot while standing)
    stand_t = a.times[-1] + np.arange(1, 151) / 100.0
    stand = np.concatenate([np.repeat(m1.positions[-1:], 75, axis=0),
                            np.repeat(m2.positions[:1], 75, axis=0)])
    t = np.concatenate([a.times, stand_t, stand_t[-1] + 0.01 + b.times])
    P = np.concatenate([m1.positions, stand, m2.positions])
    m = MarkerTrajectories(t, P, m1.labels, 100.0, "m")
    g = GaitAnalysis("crossing").fit(feet_from_markers(m))
    assert len(g.passes_) == 2
    d0, d1 = (np.array(p.direction) for p in g.passes_)
    assert d0 @ d1 < -0.99
    # Pass 2 starts after standing: its first step and first stride are excluded.
    assert g.passes_[1].excluded_first and not g.passes_[0].excluded_first
    for s in g.steps_:
        assert s.length_m == pytest.approx(0.7, abs=0.005)
        assert s.width_m == pytest.approx(0.12, abs=0.005)
    assert {s.pass_index for s in g.steps_} == {0, 1}


def test_fewer_than_two_steps_is_a_clear_error() -> None:
    w = synth_walk(n_steps=2)
    m = walk_markers(w)
    with pytest.raises(InsufficientDataError, match="step") as err:
        GaitAnalysis("crossing").fit(feet_from_markers(m))
    # it says how much walking was seen (a long walk seen over a short stretch needs
    # more sensor coverage, not a longer walk)
    seen = float(str(err.value).split("seen was ")[1].split(" m")[0])
    assert 0.5 <= seen <= 2 * 0.7 + 0.3, str(err.value)
    assert "cover more of the walkway" in str(err.value)


def test_standing_still_is_a_clear_error() -> None:
    w = synth_walk()
    m = walk_markers(w)
    m.positions[:] = m.positions[:1]
    with pytest.raises(InsufficientDataError, match="no straight walking"):
        GaitAnalysis().fit(feet_from_markers(m))


def test_missing_foot_markers_names_what_is_missing() -> None:
    w = synth_walk()
    m = walk_markers(w)
    keep = [i for i, lab in enumerate(m.labels) if not lab.startswith("R")]
    m2 = MarkerTrajectories(m.times, m.positions[:, keep], [m.labels[i] for i in keep],
                            m.rate, "m")
    with pytest.raises(InputError) as ei:
        feet_from_markers(m2)
    msg = str(ei.value)
    assert "right ankle or heel" in msg and "LHEE" in msg and "left" not in msg.split(";")[0]


def test_bad_method_and_unknown_override() -> None:
    with pytest.raises(InputError):
        GaitAnalysis("zeni")  # type: ignore[arg-type]
    m = walk_markers(synth_walk())
    with pytest.raises(InputError, match="available labels"):
        feet_from_markers(m, left="LKNEE", right="RKNEE")
    with pytest.raises(InputError, match="both"):
        feet_from_markers(m, left="LHEE")


@pytest.mark.parametrize("names", [
    {"ankleL": "Subject:L.Ankle", "ankleR": "Subject:R.Ankle"},
    {"heelL": "L_FCC", "heelR": "R_FCC"},
    {"ankleL": "LeftAnkle", "ankleR": "RightAnkle"},
    {"ankleL": "AnkleLeft", "ankleR": "AnkleRight"},
    {"ankleL": "l_ankle", "ankleR": "r_ankle"},
    {"heelL": "L.Heel", "heelR": "R.Heel"},
])
def test_marker_name_conventions(names: dict[str, str]) -> None:
    w = synth_walk()
    g = GaitAnalysis("crossing").fit(feet_from_markers(walk_markers(w, names)))
    assert np.median([s.length_m for s in g.steps_]) == pytest.approx(0.7, abs=0.005)


def test_explicit_markers_override() -> None:
    w = synth_walk()
    m = walk_markers(w)
    f = feet_from_markers(m, left="ltoe", right="RTOE")
    assert f.primary == {"L": "explicit", "R": "explicit"}
    assert f.sources["L_explicit"] == "LTOE"
    g = GaitAnalysis("crossing").fit(f)
    assert np.median([s.length_m for s in g.steps_]) == pytest.approx(0.7, abs=0.005)


def test_json_schema_is_stable() -> None:
    g = GaitAnalysis("heelstrike").fit(feet_from_markers(walk_markers(synth_walk())))
    doc = json.loads(g.to_json())
    assert set(doc) == {"events", "steps", "strides", "summary"}
    assert set(doc["events"][0]) == {"side", "kind", "time_s"}
    assert {e["kind"] for e in doc["events"]} == {"foot_strike", "foot_off"}
    assert set(doc["steps"][0]) == {"side", "time_s", "length_m", "width_m", "duration_s"}
    assert set(doc["strides"][0]) == {"side", "time_s", "length_m", "duration_s"}
    for k in ("walking_speed_m_s", "cadence_steps_min", "step_length_m", "step_width_m",
              "step_time_s", "stride_length_m", "stride_time_s", "stance_pct", "swing_pct",
              "double_support_pct", "n_steps", "n_strides", "n_passes", "method"):
        assert k in doc["summary"]
    assert set(doc["summary"]["step_length_m"]) == {"mean", "sd", "cv_pct", "left_mean",
                                                    "right_mean", "asymmetry_pct"}


def test_fit_accepts_markers_and_skeletons() -> None:
    from engine.sim.straight_walk import walk_skeleton
    from engine.skeleton import KINECT_V2, SkeletonSeries

    w = synth_walk(step_width=0.15)
    a = GaitAnalysis("crossing").fit(walk_markers(w))
    P = walk_skeleton(w)
    s = SkeletonSeries(w.times, P, np.full(P.shape[:2], 2, dtype=np.uint8), KINECT_V2)
    b = GaitAnalysis("crossing").fit(s)
    for g in (a, b):
        assert np.median([x.width_m for x in g.steps_]) == pytest.approx(0.15, abs=0.003)


def test_brief_leg_label_swap_is_ignored() -> None:
    w = synth_walk(step_length=0.7, step_width=0.12, step_time=0.55)
    m = walk_markers(w)
    iL, iR = m.labels.index("LANK"), m.labels.index("RANK")
    sw = (m.times > 2.1) & (m.times < 2.28)  # a tracker swapping the legs for 0.18 s
    m.positions[sw, iL], m.positions[sw, iR] = (m.positions[sw, iR].copy(),
                                                m.positions[sw, iL].copy())
    g = GaitAnalysis("crossing").fit(feet_from_markers(m))
    placements = [e.time_s for e in g.events_]
    assert not any(2.05 < t < 2.35 for t in placements)
    assert len(g.steps_) >= 7
    for s in g.steps_:
        assert s.length_m == pytest.approx(0.7, abs=0.003)
        assert s.duration_s == pytest.approx(0.55, abs=0.011)


def test_auto_exclusion_when_recording_starts_while_accelerating() -> None:
    w = synth_walk(n_steps=12)
    m = walk_markers(w)
    dt = 0.01
    tau = np.arange(0.0, 6.0, dt)
    rate = 0.3 + 0.7 * np.minimum(tau / 1.5, 1.0)  # speeding up from 30 % over 1.5 s
    g = np.cumsum(rate) * dt
    tau, g = tau[g < w.times[-1]], g[g < w.times[-1]]
    P = np.stack([np.stack([np.interp(g, w.times, m.positions[:, i, k]) for k in range(3)], -1)
                  for i in range(len(m.labels))], 1)
    acc = MarkerTrajectories(tau, P, m.labels, 100.0, "m")
    ga = GaitAnalysis("crossing").fit(feet_from_markers(acc))
    assert ga.passes_[0].excluded_first
    steady = GaitAnalysis("crossing").fit(feet_from_markers(m))
    assert not steady.passes_[0].excluded_first
    assert len(ga.steps_) == len(ga.events_) - 2  # first step dropped


def test_events_missed_on_both_feet_do_not_make_a_giant_step() -> None:
    w = synth_walk(step_length=0.7, step_time=0.55, n_steps=12)
    m = walk_markers(w)
    # both ankles lost for 0.9 s (longer than any gap bridging): two placements missed
    gone = (m.times > 2.3) & (m.times < 3.2)
    m.positions[gone] = np.nan
    g = GaitAnalysis("crossing", exclude_first=False).fit(feet_from_markers(m))
    assert all(s.duration_s == pytest.approx(0.55, abs=0.011) for s in g.steps_)
    assert all(s.duration_s == pytest.approx(1.1, abs=0.011) for s in g.strides_)
    assert all(s.length_m == pytest.approx(0.7, abs=0.005) for s in g.steps_)


def test_stance_median_placement_reduces_noise() -> None:
    w = synth_walk(step_width=0.12, n_steps=30)
    m = walk_markers(w)
    rng = np.random.default_rng(0)
    m.positions = m.positions + rng.normal(0, 0.01, m.positions.shape)  # 1 cm jitter
    f = feet_from_markers(m)
    sd = {}
    for win in (0.0, 0.1):
        g = GaitAnalysis("crossing", placement_window_s=win).fit(f)
        widths = np.array([s.width_m for s in g.steps_])
        assert abs(widths.mean() - 0.12) < 0.004
        sd[win] = widths.std()
    assert sd[0.1] < 0.6 * sd[0.0]
    with pytest.raises(InputError):
        GaitAnalysis(placement_window_s=1.0)


def test_stance_placement_averages_the_whole_stance(monkeypatch: pytest.MonkeyPatch) -> None:
    """A slow walk's stance (≈ 0.8 s here) outlasts the ±0.3 s window. Tracker errors are
    correlated over ≈ 0.3 s (SIM model ``slow_tau_s``), so only more of the stance, not
    more samples of the same stretch, averages them down: extending the average over the
    rest of the stance makes steps more precise against the truth, and no less accurate."""
    from scipy.signal import lfilter

    w = synth_walk(step_length=0.6, step_width=0.12, step_time=0.7, n_steps=40, rate=30.0,
                   double_support_s=0.2)
    rng = np.random.default_rng(0)
    a = np.exp(-(1 / 30) / 0.3)  # AR(1) of 0.3 s correlation time, 1 cm SD
    err: dict[float, list[float]] = {0.0: [], 0.5: []}
    for _ in range(3):
        m = walk_markers(w)
        m.positions = m.positions + lfilter([np.sqrt(1 - a * a)], [1, -a],
                                            rng.normal(0, 0.01, m.positions.shape), axis=0)
        f = feet_from_markers(m)
        for ext in list(err):
            monkeypatch.setattr(gait, "STANCE_MAX_HALF_S", ext)  # 0: the window only
            g = GaitAnalysis("crossing").fit(f)
            assert len(g.steps_) >= 36
            assert abs(np.mean([s.width_m for s in g.steps_]) - 0.12) < 0.004
            assert abs(np.mean([s.length_m for s in g.steps_]) - 0.6) < 0.003
            err[ext] += ([s.width_m - 0.12 for s in g.steps_]
                         + [s.length_m - 0.6 for s in g.steps_])
    var = {k: float(np.mean(np.square(v))) for k, v in err.items()}
    assert var[0.5] < 0.87 * var[0.0]  # measured ≈ 0.71–0.80 over six noise draws


def test_find_passes_straight_run_shorter_than_baseline_after_start() -> None:
    """Regression (IndexError → HTTP 500 on a real recording): a subject standing, then
    shifting 13 cm within 0.4 s, then standing again gives a "straight walking" run of
    fewer samples than the ±0.25 s baseline, starting after sample 0; trimming its ends
    leaves nothing, which must be skipped, not indexed."""
    from scipy.ndimage import uniform_filter1d

    rate = 30.0
    t = np.arange(0.0, 6.0, 1.0 / rate)
    x = 0.13 * np.clip((t - 3.0) / 0.4, 0.0, 1.0)
    centre = np.stack([x, np.zeros_like(t), np.full_like(t, 0.9)], axis=1)
    # Precondition, with find_passes' own smoothing and baseline: the run is 1..k
    # samples long and does not start at sample 0.
    k = round(0.25 * rate)
    cs = uniform_filter1d(centre[:, :2], round(0.8 * rate), axis=0, mode="nearest")
    n = len(t)
    ia, ib = np.clip(np.arange(n) - k, 0, n - 1), np.clip(np.arange(n) + k, 0, n - 1)
    speed = np.linalg.norm(cs[ib] - cs[ia], axis=1) / (t[ib] - t[ia])
    run = np.flatnonzero(speed > gait.MIN_WALK_SPEED)
    assert 1 <= len(run) <= k and run[0] > 0
    assert gait.find_passes(t, centre, rate) == []
    # and the analysis says what is missing instead of crashing
    feet = FeetTrajectories(t, rate, {"L": {"ankle": centre + np.array([0.0, 0.06, -0.8])},
                                      "R": {"ankle": centre + np.array([0.0, -0.06, -0.8])}},
                            {"L": "ankle", "R": "ankle"}, pelvis=centre)
    with pytest.raises(InsufficientDataError, match="no straight walking"):
        GaitAnalysis("crossing").fit(feet)


def test_fixed_walkway_axis_rotated_from_the_walk_biases_widths_antisymmetrically() -> None:
    """Seed 000's left/right step-width bias pattern: widths measured along a fixed axis
    2° off the line of progression are w ± ψ·L (left steps wider here, right narrower),
    while the footprint direction (default) measures the true width."""
    w = synth_walk(step_length=0.7, step_width=0.12, step_time=0.55, heading_deg=2.0)
    feet = feet_from_markers(walk_markers(w))
    psi = np.radians(2.0)
    fixed = GaitAnalysis("crossing", direction=(1.0, 0.0)).fit(feet)
    for s in fixed.steps_:
        expect = 0.12 + psi * 0.7 if s.side == "L" else 0.12 - psi * 0.7
        assert s.width_m == pytest.approx(expect, abs=0.002)
    auto = GaitAnalysis("crossing").fit(feet)
    assert all(s.width_m == pytest.approx(0.12, abs=0.002) for s in auto.steps_)
    with pytest.raises(InputError, match="direction"):
        GaitAnalysis(direction=(0.0, 0.0))


def _standing_start_walk(noise_m: float = 0.0, seed: int = 0
                         ) -> tuple[FeetTrajectories, list[tuple[str, float]]]:
    """A subject standing 1 s, then walking 6 m starting with the left foot (seed 000's
    protocol), ankles at 100 Hz; also the true footprints (side, x of the heel)."""
    from engine.mocap import feet_from_skeleton
    from engine.sim.walker import Walker, WalkerParams
    from engine.skeleton import KINECT_V2, SkeletonSeries, TrackingState

    w = Walker(WalkerParams(), np.array([0.0, 0.0, 0.0]), np.array([8.0, 0.0, 0.0]),
               start_time=1.0, back_and_forth=False, seed=seed, horizon_s=12.0)
    t = np.arange(0.0, 6.0, 0.01)
    J = w.joints(t)
    J += np.random.default_rng(seed).normal(0.0, noise_m, J.shape)
    s = SkeletonSeries(t, J, np.full(J.shape[:2], TrackingState.TRACKED, np.uint8), KINECT_V2)
    prints = [("L" if sd == 1 else "R", float(h[0])) for sd, h in zip(w._s.side, w._s.heel,
                                                                     strict=True)]
    return feet_from_skeleton(s), prints


@pytest.mark.parametrize("noise_m", [0.0, 0.005])
def test_start_from_standing_first_step_is_the_first_foot(noise_m: float) -> None:
    # Standing feet side by side never cross: the first crossing is the right foot
    # passing the landed left foot. The standing right foot is the placement before it,
    # so the first step is the LEFT one (seed 000 Fig. 6) and it is the short one.
    feet, prints = _standing_start_walk(noise_m)
    g = GaitAnalysis("crossing", exclude_first=False).fit(feet)
    first = g.events_[0]
    assert (first.side, first.kind) == ("R", "placement")
    assert 0.8 <= first.time_s <= 1.3  # when the left foot leaves the right one
    assert [s.side for s in g.steps_[:3]] == ["L", "R", "L"]
    # footprints: two standing, then the first (shortened) left step
    true_first = prints[2][1] - prints[1][1]
    assert g.steps_[0].length_m == pytest.approx(true_first, abs=0.02)
    assert g.steps_[0].length_m < 0.8 * g.steps_[2].length_m
    assert g.strides_[0].side == "R"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_start_from_standing_found_through_kinect_like_wander_and_dropouts(seed: int) -> None:
    # A fused Kinect ankle of a standing subject wanders by several cm within a few
    # tenths of a second (slowly varying fit error, SD 3 cm here) and the far foot, partly
    # hidden by the other leg, drops out for single frames: neither is a step.
    from engine.mocap import feet_from_skeleton
    from engine.sim.walker import Walker, WalkerParams
    from engine.skeleton import KINECT_V2, SkeletonSeries, TrackingState

    w = Walker(WalkerParams(), np.array([0.0, 0.0, 0.0]), np.array([8.0, 0.0, 0.0]),
               start_time=1.5, back_and_forth=False, seed=seed, horizon_s=12.0)
    t = np.arange(0.0, 6.0, 1 / 30)
    J = w.joints(t)
    rng = np.random.default_rng(seed)
    a = np.exp(-(1 / 30) / 0.3)  # AR(1), correlation time 0.3 s
    e = np.zeros(J.shape)
    e[0] = rng.normal(0.0, 0.03, J.shape[1:])
    for i in range(1, len(t)):
        e[i] = a * e[i - 1] + rng.normal(0.0, 0.03 * np.sqrt(1 - a * a), J.shape[1:])
    J = J + e
    states = np.full(J.shape[:2], TrackingState.TRACKED, np.uint8)
    right = [KINECT_V2.index(n) for n in ("AnkleRight", "FootRight")]
    drop = (np.arange(len(t)) % 4 == 0) & (t < 1.5)
    states[np.ix_(drop, right)] = TrackingState.NOT_TRACKED
    J[np.ix_(drop, right)] = np.nan
    feet = feet_from_skeleton(SkeletonSeries(t, J, states, KINECT_V2))
    g = GaitAnalysis("crossing", exclude_first=False).fit(feet)
    first = g.events_[0]
    assert (first.side, first.kind) == ("R", "placement")
    assert 1.0 <= first.time_s <= 1.8
    assert [s.side for s in g.steps_[:2]] == ["L", "R"]


@pytest.mark.parametrize("rule", ["auto", True, "L"])
def test_start_from_standing_excludes_first_left_step_and_first_right_stride(
        rule: bool | str) -> None:
    feet, _ = _standing_start_walk()
    every = GaitAnalysis("crossing", exclude_first=False).fit(feet)
    g = GaitAnalysis("crossing", exclude_first=rule).fit(feet)  # type: ignore[arg-type]
    assert g.steps_ == every.steps_[1:]
    assert every.strides_[0].side == "R" and g.strides_ == every.strides_[1:]


def _hide_right_through_first_left_landing(feet: FeetTrajectories) -> FeetTrajectories:
    """The tracker lost the right ankle during its first swing: the crossing that gives the
    left foot's first placement is missed."""
    every = GaitAnalysis("crossing", exclude_first=False).fit(feet)
    t_left_placed = every.events_[1].time_s
    R = feet.foot("R")
    R[(feet.times > t_left_placed - 0.35) & (feet.times < t_left_placed + 0.2)] = np.nan
    return feet


@pytest.mark.parametrize("rule", ["auto", True, "L"])
def test_missed_first_landing_after_a_known_standing_drops_no_normal_step(
        rule: bool | str) -> None:
    # The standing right foot is found, the left foot's first landing is not: the first
    # left step and first right stride (both from the standing foot) were never measured,
    # and the steps found after them are normal ones, kept.
    feet = _hide_right_through_first_left_landing(_standing_start_walk()[0])
    missed = GaitAnalysis("crossing", exclude_first=False).fit(feet)
    assert [e.side for e in missed.events_[:2]] == ["R", "R"]  # standing R, then R again
    g = GaitAnalysis("crossing", exclude_first=rule).fit(feet)  # type: ignore[arg-type]
    assert g.steps_ == missed.steps_ and g.strides_ == missed.strides_


def test_literal_rule_without_standing_drops_the_first_left_step_found() -> None:
    # Recording started after the subject left: no standing seen. The paper's literal
    # rule drops the first LEFT step and first RIGHT stride found.
    feet, _ = _standing_start_walk()
    feet = _hide_right_through_first_left_landing(feet)
    for f in ("L", "R"):
        feet.foot(f)[feet.times < 1.5] = np.nan
    missed = GaitAnalysis("crossing", exclude_first=False).fit(feet)
    literal = GaitAnalysis("crossing", exclude_first="L").fit(feet)
    first_left = next(s for s in missed.steps_ if s.side == "L")
    assert first_left not in literal.steps_ and len(literal.steps_) == len(missed.steps_) - 1
    first_right_stride = next(s for s in missed.strides_ if s.side == "R")
    assert first_right_stride not in literal.strides_


def test_exclude_first_rejects_unknown_rule() -> None:
    with pytest.raises(InputError, match="exclude_first"):
        GaitAnalysis("crossing", exclude_first="left")  # type: ignore[arg-type]


def test_heelstrike_steps_are_footprint_to_footprint_for_ankle_joints() -> None:
    """A skeleton has ankles, no heels: at one foot's strike the other's ankle has already
    risen and rolled forward over its toes. Steps run from footprint to footprint (each
    foot at its own strike), so heel strike and crossing agree on the same walk; taking
    both ankles at the strike instant made the walker's steps ≈ 8 cm short."""
    from engine.sim.walker import Walker, WalkerParams
    from engine.skeleton import KINECT_V2, SkeletonSeries

    w = Walker(WalkerParams(), [0.0, 0.0, 0.0], [9.0, 0.0, 0.0], start_time=1.0,
               back_and_forth=False, seed=3, horizon_s=20.0)
    t = np.arange(0.0, 8.0, 0.01)
    J = w.joints(t)
    s = SkeletonSeries(t, J, np.full(J.shape[:2], 2, dtype=np.uint8), KINECT_V2)
    cross, heel = GaitAnalysis("crossing").fit(s), GaitAnalysis("heelstrike").fit(s)
    assert len(heel.steps_) >= 6
    for key in ("length_m", "width_m"):
        a = np.median([getattr(x, key) for x in cross.steps_])
        b = np.median([getattr(x, key) for x in heel.steps_])
        assert b == pytest.approx(a, abs=0.01), key
    assert heel.summary_["walking_speed_m_s"] == pytest.approx(
        cross.summary_["walking_speed_m_s"], rel=0.03)


# ------------------------------------------------------------------ research API


def test_to_records_gives_flat_tables_in_si_units() -> None:
    w = synth_walk(step_length=0.7, step_width=0.1, step_time=0.55, rate=100.0)
    g = GaitAnalysis("heelstrike").fit(walk_markers(w))
    steps = g.to_records("steps")
    assert len(steps) == len(g.steps_) >= 4
    assert set(steps[0]) == {"side", "time_s", "length_m", "width_m", "duration_s",
                             "pass_index"}
    assert [r["length_m"] for r in steps] == [s.length_m for s in g.steps_]
    assert all(r["length_m"] == pytest.approx(0.7, abs=0.01) for r in steps)
    assert set(g.to_records("strides")[0]) == {"side", "time_s", "length_m", "duration_s",
                                               "pass_index"}
    events = g.to_records("events")
    assert {r["kind"] for r in events} == {"foot_strike", "foot_off"}
    assert [r["time_s"] for r in events] == sorted(r["time_s"] for r in events)
    (p,) = g.to_records("passes")
    assert p["pass_index"] == 0 and p["t_start_s"] < p["t_end_s"]
    assert p["direction_x"] == pytest.approx(1.0, abs=0.01)  # synth_walk walks along +x
    summary = {r["parameter"]: r for r in g.to_records("summary")}
    assert summary["step_length_m"]["mean"] == g.summary_["step_length_m"]["mean"]
    assert summary["walking_speed_m_s"]["mean"] == pytest.approx(0.7 / 0.55, rel=0.02)
    assert summary["walking_speed_m_s"]["sd"] is None
    assert set(summary["stance_pct"]) == {"parameter", "mean", "sd", "cv_pct", "left_mean",
                                          "right_mean", "asymmetry_pct"}
    assert "method" not in summary and "n_steps" not in summary
    # plain Python values all through: json (and pandas) take the rows as they are
    json.dumps([steps, events, summary, p])
    with pytest.raises(InputError, match="unknown table 'footprints'"):
        g.to_records("footprints")  # type: ignore[arg-type]


def test_summary_values_are_python_floats() -> None:
    g = GaitAnalysis("heelstrike").fit(walk_markers(synth_walk(rate=100.0)))
    for key in ("stance_pct", "swing_pct"):
        for v in g.summary_[key].values():
            assert type(v) is float, (key, v)


def test_fit_takes_a_file_path(tmp_path: object) -> None:
    from pathlib import Path

    from engine.io.trc import write_trc

    f = Path(str(tmp_path)) / "walk.trc"
    write_trc(f, walk_markers(synth_walk(step_length=0.66)))
    for arg in (f, str(f)):
        g = GaitAnalysis().fit(arg)
        assert g.summary_["step_length_m"]["mean"] == pytest.approx(0.66, abs=0.01)
    with pytest.raises(InputError, match="not found"):
        GaitAnalysis().fit(f.with_name("missing.trc"))


def test_fit_of_another_type_and_results_before_fit_are_clear_errors() -> None:
    with pytest.raises(InputError, match=r"FeetTrajectories .* not ndarray"):
        GaitAnalysis().fit(np.zeros((100, 3)))  # type: ignore[arg-type]
    g = GaitAnalysis()
    for call in (g.to_dict, g.to_records, g.marker_events, g.to_json):
        with pytest.raises(InputError, match=r"call fit\(\.\.\.\) first"):
            call()


def test_reprs_summarise_instead_of_printing_arrays() -> None:
    from engine.sim.straight_walk import walk_skeleton
    from engine.skeleton import KINECT_V2, SkeletonSeries

    w = synth_walk(rate=100.0)
    m = walk_markers(w)
    feet = feet_from_markers(m)
    P = walk_skeleton(w)
    s = SkeletonSeries(w.times, P, np.full(P.shape[:2], 2, dtype=np.uint8), KINECT_V2)
    for obj, words in ((m, ["MarkerTrajectories(", "100 Hz", "markers", "LHEE"]),
                       (feet, ["FeetTrajectories(", "100 Hz", "'heel'", "pelvis=yes"]),
                       (s, ["SkeletonSeries(kinect_v2", f"{len(w.times)} frames",
                            "100 % of joints tracked"])):
        text = repr(obj)
        assert len(text) < 800, text
        for word in words:
            assert word in text, (word, text)


def test_an_up_that_is_no_axis_is_named_as_such() -> None:
    m = walk_markers(synth_walk())
    with pytest.raises(InputError, match=r"must be one of x, y, z .* got 'w'"):
        feet_from_markers(m, up="w")
    with pytest.raises(InputError, match="contradicts the markers"):
        feet_from_markers(m, up="y")  # an axis, but the wrong one


def _one_sided_view(hide_s: float, rate: float = 30.0) -> tuple[FeetTrajectories,
                                                                 GaitAnalysis]:
    """A 30 Hz skeleton walk whose left ankle (the far leg, seen from the right) is lost
    for ``hide_s`` around every crossing of the ankles, as a sensor group on one side of
    the walkway loses it behind the near leg; and the analysis of the walk in full view."""
    from engine.mocap import feet_from_skeleton
    from engine.sim.straight_walk import walk_skeleton
    from engine.skeleton import KINECT_V2, SkeletonSeries, TrackingState

    w = synth_walk(step_length=0.7, step_width=0.12, step_time=0.55, n_steps=14, rate=rate)
    P = walk_skeleton(w)
    states = np.full(P.shape[:2], TrackingState.TRACKED, np.uint8)
    full = GaitAnalysis("crossing", exclude_first=False).fit(
        feet_from_skeleton(SkeletonSeries(w.times, P, states, KINECT_V2)))
    ankle = KINECT_V2.joints.index("AnkleLeft")
    for e in full.events_:
        hidden = np.abs(w.times - e.time_s) <= hide_s / 2
        P[hidden, ankle] = np.nan
        states[hidden, ankle] = TrackingState.NOT_TRACKED
    return feet_from_skeleton(SkeletonSeries(w.times, P, states, KINECT_V2)), full


@pytest.mark.parametrize("window", [0.3, 0.0])
def test_crossings_hidden_in_a_gap_of_the_far_ankle_are_found(window: float) -> None:
    """Seen from one side, the far ankle is hidden behind the near leg as it passes it:
    0.3 s gaps (longer than the 0.2 s that are filled) at every crossing lost the
    placements there and the steps around them (a one-sided report of a 14 s recording
    found 2 of its 8 steps)."""
    feet, full = _one_sided_view(0.3)
    assert np.isnan(feet.foot("L")[:, 0]).sum() > 8 * 8  # the gaps are there, unfilled
    g = GaitAnalysis("crossing", exclude_first=False, placement_window_s=window).fit(feet)
    assert len(g.steps_) == len(full.steps_) >= 11
    for s, ref in zip(g.steps_, full.steps_, strict=True):
        assert s.side == ref.side
        assert s.time_s == pytest.approx(ref.time_s, abs=0.02)
        assert s.length_m == pytest.approx(ref.length_m, abs=0.005)
        assert s.width_m == pytest.approx(ref.width_m, abs=0.003)
        assert s.duration_s == pytest.approx(ref.duration_s, abs=0.03)
    # Without bridging (the paper's data) those crossings are missed.
    strict = GaitAnalysis("crossing", exclude_first=False, placement_window_s=window,
                          max_crossing_gap_s=0.0)
    with pytest.raises(InsufficientDataError):
        assert len(strict.fit(feet).steps_) < len(full.steps_) // 2


def test_a_gap_longer_than_max_crossing_gap_is_not_bridged() -> None:
    feet, full = _one_sided_view(0.45)  # gaps of 0.47 s between the samples around them
    g = GaitAnalysis("crossing", exclude_first=False, max_crossing_gap_s=0.4)
    with pytest.raises(InsufficientDataError):
        g.fit(feet)
    # the default 0.5 s bridges them (the left ankle is seen for 0.1 s per step here,
    # so the steps at the walk's two ends, whose gaps are not closed, are lost)
    assert len(GaitAnalysis("crossing", exclude_first=False).fit(feet).steps_) \
        >= len(full.steps_) - 2
    with pytest.raises(InputError, match="max_crossing_gap_s"):
        GaitAnalysis(max_crossing_gap_s=1.5)


def test_a_short_gap_of_the_body_centre_does_not_split_a_pass() -> None:
    rate = 30.0
    t = np.arange(0.0, 6.0, 1.0 / rate)
    centre = np.stack([1.2 * t, np.zeros_like(t), np.full_like(t, 0.9)], axis=1)
    centre[(t > 3.0) & (t < 3.35)] = np.nan
    passes = gait.find_passes(t, centre, rate)
    assert len(passes) == 1 and passes[0].t_end - passes[0].t_start > 5.0
    centre[(t > 3.0) & (t < 3.7)] = np.nan  # longer than MAX_CENTRE_GAP_S: two passes
    assert len(gait.find_passes(t, centre, rate)) == 2
