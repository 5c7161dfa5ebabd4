"""Multi-sensor skeleton integration against synthetic ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from engine.errors import InputError, InsufficientDataError
from engine.gait import GaitAnalysis
from engine.integration import (
    SensorStream,
    correct_timestamps,
    integrate_skeletons,
    lowpass,
)
from engine.mocap import feet_from_skeleton
from engine.sim.straight_walk import (
    sample_truth,
    six_sensor_streams,
    synth_walk,
    walk_skeleton,
)
from engine.skeleton import AZURE_KINECT, KINECT_V2, SkeletonSeries, TrackingState


@pytest.fixture(scope="module")
def walk():  # type: ignore[no-untyped-def]
    return synth_walk(step_length=0.7, step_width=0.12, step_time=0.55, n_steps=16,
                      rate=120.0, origin=(-1.0, 0.0, 0.0))


def _rms_vs_truth(w, fused: SkeletonSeries, joint: str) -> float:  # type: ignore[no-untyped-def]
    truth = sample_truth(w, walk_skeleton(w), fused.times)
    j = KINECT_V2.index(joint)
    e = np.linalg.norm(fused.positions[:, j] - truth[:, j], axis=1)
    return float(np.sqrt(np.nanmean(e**2)))


def test_clock_offsets_and_drift_are_corrected(walk) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(3)
    streams = six_sensor_streams(walk, rng, occluded_bias_m=0.0, inferred_frac=0.0)
    assert max(abs(s.clock_offset_s) for s in streams) > 0.2
    fused, rep = integrate_skeletons(streams, "mean")
    assert np.allclose(np.diff(fused.times), 1 / 30)
    assert np.allclose(fused.times * 30, np.round(fused.times * 30))
    assert rep.clock_offsets_s == {s.sensor_id: s.clock_offset_s for s in streams}
    ok = _rms_vs_truth(walk, fused, "AnkleLeft")
    # The same data with the clock model ignored: sensors disagree by up to ~1 s.
    for s in streams:
        s.clock_offset_s, s.clock_drift_ppm = 0.0, 0.0
    bad, _ = integrate_skeletons(streams, "mean")
    assert ok < 0.012
    assert _rms_vs_truth(walk, bad, "SpineBase") > 0.08


def test_correct_timestamps_inverts_clock_model() -> None:
    t = np.linspace(0, 100, 11)
    local = 0.37 + (1 + 80e-6) * t
    np.testing.assert_allclose(correct_timestamps(local, 0.37, 80.0), t, atol=1e-12)


def test_short_gaps_filled_and_reported_long_gaps_left(walk) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(4)
    short = six_sensor_streams(walk, rng, inferred_frac=0.0, clocks=False, drop=(2.0, 2.12))
    fused, rep = integrate_skeletons(short, "mean")
    assert rep.tracked_pct["AnkleLeft"] < 100.0
    gaps = [g for g in rep.gaps_filled if g.joint == "AnkleLeft"]
    # every sensor that saw the subject around t = 2 s reports its bridged gap
    assert len({g.source for g in gaps}) >= 2
    for g in gaps:
        assert g.t_start < 2.0 + 1e-6 and g.t_end > 2.12 - 1e-6 and g.t_end - g.t_start <= 0.2
    m = (fused.times > 2.01) & (fused.times < 2.11)
    j = KINECT_V2.index("AnkleLeft")
    assert np.all(fused.states[m, j] == TrackingState.INFERRED)
    assert np.isfinite(fused.positions[m, j]).all()
    away = (np.abs(fused.times - 2.06) > 0.15) & (fused.times > 0.5) & (fused.times < 8.0)
    assert np.all(fused.states[away, j] == TrackingState.TRACKED)
    assert rep.filled_pct["AnkleLeft"] > 0 and not rep.gaps_unfilled

    long_ = six_sensor_streams(walk, rng, inferred_frac=0.0, clocks=False, drop=(2.0, 2.5))
    fused, rep = integrate_skeletons(long_, "mean")
    m = (fused.times > 2.01) & (fused.times < 2.49)
    assert np.isnan(fused.positions[m, j]).all()
    assert np.all(fused.states[m, j] == TrackingState.NOT_TRACKED)
    assert any(g.joint == "AnkleLeft" and g.t_end - g.t_start > 0.2 for g in rep.gaps_unfilled)


def test_inferred_joints_are_missing_values(walk) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(5)
    streams = six_sensor_streams(walk, rng, occluded_bias_m=0.0, inferred_frac=0.0)
    s0 = streams[0].series
    j = KINECT_V2.index("KneeLeft")
    s0.positions[:, j] += 1.0  # a wild inferred guess ...
    s0.states[:, j] = TrackingState.INFERRED  # ... flagged as such
    fused, rep = integrate_skeletons(streams, "mean")
    assert _rms_vs_truth(walk, fused, "KneeLeft") < 0.02
    assert rep.sensors_per_sample < 6


def test_kept_states_can_keep_inferred_joints(walk) -> None:  # type: ignore[no-untyped-def]
    """``kept_states=(TRACKED, INFERRED)`` (the paper's Discussion: only untracked joints
    ignored) averages a sensor's INFERRED guesses in; NOT_TRACKED stays missing, the
    default is unchanged and any other choice of states is refused."""
    rng = np.random.default_rng(5)
    streams = six_sensor_streams(walk, rng, occluded_bias_m=0.0, inferred_frac=0.0)
    j = KINECT_V2.index("KneeLeft")
    for s in streams:
        s.series.states[:, j] = TrackingState.INFERRED  # every sensor's knee guessed ...
    streams[0].series.positions[:, j] += 1.0  # ... one of them wildly
    default, rep0 = integrate_skeletons(streams, "mean")
    assert np.isnan(default.positions[:, j]).all()
    assert "kept_states" not in default.meta
    both = (TrackingState.TRACKED, TrackingState.INFERRED)
    kept, rep = integrate_skeletons(streams, "mean", kept_states=both)
    assert kept.meta["kept_states"] == ["INFERRED", "TRACKED"]
    assert _rms_vs_truth(walk, kept, "KneeLeft") > 0.05  # the wild guess is averaged in
    assert rep0.tracked_pct["KneeLeft"] == 0.0 and rep.tracked_pct["KneeLeft"] > 90.0
    # a NOT_TRACKED joint is missing whatever is kept
    for s in streams:
        s.series.states[:, j] = TrackingState.NOT_TRACKED
    none, _ = integrate_skeletons(streams, "mean", kept_states=both)
    assert np.isnan(none.positions[:, j]).all()
    for bad in ((TrackingState.INFERRED,), (TrackingState.TRACKED, TrackingState.NOT_TRACKED)):
        with pytest.raises(InputError, match="kept_states"):
            integrate_skeletons(streams, "mean", kept_states=bad)


def test_weighted_removes_side_bias_that_mean_keeps(walk) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(6)
    # Each sensor pulls joints toward itself: 1.5 cm on the half it faces, 3.5 cm on the
    # half turned away (seed 000 Fig. 5B; SIM error model defaults).
    streams = six_sensor_streams(walk, rng, occluded_bias_m=0.035, near_bias_m=0.015)
    res = {}
    for est in ("mean", "weighted"):
        fused, _ = integrate_skeletons(streams, est)  # type: ignore[arg-type]
        g = GaitAnalysis("crossing").fit(feet_from_skeleton(fused))
        res[est] = (np.mean([s.width_m for s in g.steps_]) - 0.12,
                    np.mean([s.length_m for s in g.steps_]) - 0.7, len(g.steps_))
    # the mean narrows the steps by about (3.5 − 1.5) cm ...
    assert res["mean"][0] < -0.015
    # ... which the view-weighted estimator mostly removes
    assert abs(res["weighted"][0]) < 0.35 * abs(res["mean"][0])
    assert abs(res["weighted"][1]) < 0.01 and res["weighted"][2] >= 10


def test_weighted_equals_mean_without_side_information(walk) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(8)
    streams = six_sensor_streams(walk, rng, occluded_bias_m=0.0, noise_m=0.0,
                                 inferred_frac=0.0)
    a, _ = integrate_skeletons(streams, "mean")
    b, _ = integrate_skeletons(streams, "weighted", surface_bias_m=0.0)
    # noise-free, unbiased sensors: any weighting gives the truth (up to the sensors'
    # linear-interpolation differences at landings, < 2 mm)
    np.testing.assert_allclose(a.positions, b.positions, atol=2e-3, equal_nan=True)


def test_weighted_rejects_an_outlier_sensor(walk) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(7)
    streams = six_sensor_streams(walk, rng, occluded_bias_m=0.0, inferred_frac=0.0,
                                 clocks=False)
    j = KINECT_V2.index("AnkleRight")
    bad = streams[3].series  # a right-side sensor swaps feet: 25 cm off, "tracked"
    bad.positions[:, j] += np.array([0.0, 0.25, 0.0])
    e_mean = _rms_vs_truth(walk, integrate_skeletons(streams, "mean")[0], "AnkleRight")
    e_w = _rms_vs_truth(walk, integrate_skeletons(streams, "weighted")[0], "AnkleRight")
    assert e_mean > 0.03
    assert e_w < 0.015


def test_lowpass_zero_phase() -> None:
    t = np.arange(0, 10, 1 / 30)
    slow = np.sin(2 * np.pi * 1.0 * t)
    fast = 0.3 * np.sin(2 * np.pi * 12.0 * t)
    y = lowpass((slow + fast)[:, None], 30.0, 6.0)[:, 0]
    inner = slice(30, -30)
    assert np.max(np.abs(y[inner] - slow[inner])) < 0.03  # no lag, 12 Hz removed
    with pytest.raises(InputError):
        lowpass(slow[:, None], 30.0, 20.0)


def test_bad_input() -> None:
    with pytest.raises(InputError):
        integrate_skeletons([])
    s = SkeletonSeries(np.arange(3) / 30, np.zeros((3, 25, 3)), np.full((3, 25), 2), KINECT_V2)
    a = SkeletonSeries(np.arange(3) / 30, np.zeros((3, 32, 3)), np.full((3, 32), 2), AZURE_KINECT)
    with pytest.raises(InputError, match="joint set"):
        integrate_skeletons([SensorStream(s, np.eye(4)), SensorStream(a, np.eye(4))])
    with pytest.raises(InputError, match="estimator"):
        integrate_skeletons([SensorStream(s, np.eye(4))], "median")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="4×4"):
        integrate_skeletons([SensorStream(s, np.eye(3))])
    one = SkeletonSeries(np.array([0.0]), np.zeros((1, 25, 3)), np.full((1, 25), 2), KINECT_V2)
    with pytest.raises(InsufficientDataError):
        integrate_skeletons([SensorStream(one, np.eye(4))])


def test_sensor_subset_one_sided(walk) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(10)
    streams = six_sensor_streams(walk, rng, occluded_bias_m=0.035, near_bias_m=0.015)
    left = [s.sensor_id for s in streams if s.T_world_sensor[1, 3] > 0]
    one, rep1 = integrate_skeletons(streams, "mean", sensors=left)
    two, rep2 = integrate_skeletons(streams, "mean")
    assert set(rep1.sensors_contributing) == set(left) and len(rep2.sensors_contributing) == 6
    # seen from the left only, the right ankle is biased (pulled toward the left sensors)
    e1 = _rms_vs_truth(walk, one, "AnkleRight")
    e2 = _rms_vs_truth(walk, two, "AnkleRight")
    assert e1 > e2
    with pytest.raises(InputError, match="unknown sensor"):
        integrate_skeletons(streams, sensors=["S9"])


def test_weighted_removes_the_visible_surface_bias(walk) -> None:  # type: ignore[no-untyped-def]
    """Every sensor fits each limb to the surface it sees: its limb joints lie 1.5 cm
    towards it along the horizontal line of sight (seed 000 Fig. 5). The mean keeps the
    bias of whichever sensors see a joint; the weighted estimator moves each sensor's
    estimate back and lands on the truth; without the correction it would not."""
    from engine.geometry import transform_points

    rng = np.random.default_rng(11)
    streams = six_sensor_streams(walk, rng, occluded_bias_m=0.0, noise_m=0.0,
                                 inferred_frac=0.0, clocks=False)
    limb = np.array(["Left" in n or "Right" in n for n in KINECT_V2.joints])
    for s in streams:
        T = np.asarray(s.T_world_sensor)
        P = transform_points(T, s.series.positions)
        u = T[:3, 3] - P
        u[..., 2] = 0.0
        u /= np.linalg.norm(u, axis=-1, keepdims=True)
        P[:, limb] += 0.015 * u[:, limb]
        s.series.positions[:] = transform_points(np.linalg.inv(T), P)
    e = {}
    for name, kw in (("mean", {}), ("weighted", {}), ("uncorrected", {"surface_bias_m": 0.0})):
        est = "mean" if name == "mean" else "weighted"
        fused, _ = integrate_skeletons(streams, est, cutoff_hz=None, **kw)  # type: ignore[arg-type]
        e[name] = max(_rms_vs_truth(walk, fused, j) for j in ("AnkleLeft", "AnkleRight"))
    assert e["weighted"] < 0.003
    assert e["mean"] > 0.006 and e["uncorrected"] > 0.006


def test_weighted_undoes_a_leg_label_swap_seen_by_two_sensors(walk) -> None:  # type: ignore[no-untyped-def]
    """With only two sensors on a foot, a per-sample vote cannot tell which one swapped
    the legs' labels; the lateral order of the ankles can (left ankle on the left)."""
    rng = np.random.default_rng(5)
    streams = six_sensor_streams(walk, rng, occluded_bias_m=0.0, noise_m=0.005,
                                 inferred_frac=0.0, clocks=False)
    two = [streams[2], streams[3]]  # S3 (left of the walkway) and S4 (right)
    ser = two[0].series
    legs = [(KINECT_V2.index(f"{p}Left"), KINECT_V2.index(f"{p}Right"))
            for p in ("Knee", "Ankle", "Foot")]
    sw = (ser.times > 3.0) & (ser.times < 3.25)
    for a, b in legs:
        ser.positions[sw, a], ser.positions[sw, b] = (ser.positions[sw, b].copy(),
                                                      ser.positions[sw, a].copy())
    fused, _ = integrate_skeletons(two, "weighted", surface_bias_m=0.0, cutoff_hz=None)
    # inside the swap (its first and last resampled frames mix swapped and true samples)
    sel = (fused.times > 3.05) & (fused.times < 3.2)
    truth = sample_truth(walk, walk_skeleton(walk), fused.times)
    j = KINECT_V2.index("AnkleLeft")
    err = np.linalg.norm(fused.positions[sel, j] - truth[sel, j], axis=1)
    assert sel.sum() >= 4 and np.nanmax(err) < 0.02
    mean, _ = integrate_skeletons(two, "mean", cutoff_hz=None)
    err_mean = np.linalg.norm(mean.positions[sel, j] - truth[sel, j], axis=1)
    assert np.nanmax(err_mean) > 0.05  # the equal-weight mean takes half the swap


def test_weighted_trusts_the_far_side_view_less_in_every_coordinate(walk) -> None:  # type: ignore[no-untyped-def]
    """A sensor seeing a leg from the other side of the body measures it worse, along the
    walkway as well as across it (Wang 2015). The weighted estimator's inverse-variance
    view weights take each ankle mostly from the sensors on its own side, so its
    forward coordinate (step lengths) is more precise than the equal-weight mean's."""
    from engine.geometry import transform_points

    rng = np.random.default_rng(12)
    streams = six_sensor_streams(walk, rng, occluded_bias_m=0.0, noise_m=0.0,
                                 inferred_frac=0.0, clocks=False)
    near_sd, far_sd = 0.01, 0.03
    for s in streams:
        T = np.asarray(s.T_world_sensor)
        P = transform_points(T, s.series.positions)
        side = np.sign(T[1, 3])  # +1: sensor on the walker's left (walking +X)
        for name, sgn in (("AnkleLeft", 1.0), ("AnkleRight", -1.0)):
            j = KINECT_V2.index(name)
            sd = near_sd if sgn == side else far_sd
            P[:, j] += rng.normal(0.0, sd, P[:, j].shape)
        s.series.positions[:] = transform_points(np.linalg.inv(T), P)
    truth_all = None
    err = {}
    for est in ("mean", "weighted"):
        fused, _ = integrate_skeletons(streams, est, cutoff_hz=None,  # type: ignore[arg-type]
                                       surface_bias_m=0.0)
        if truth_all is None:
            truth_all = sample_truth(walk, walk_skeleton(walk), fused.times)
        # away from the ends, where only one or two sensors see the walker
        sel = (fused.times > fused.times[0] + 1.0) & (fused.times < fused.times[-1] - 1.0)
        e = [fused.positions[sel, KINECT_V2.index(n), 0]
             - truth_all[sel, KINECT_V2.index(n), 0] for n in ("AnkleLeft", "AnkleRight")]
        err[est] = float(np.sqrt(np.nanmean(np.concatenate(e) ** 2)))
    # Equal weights let the 3 cm far views dominate (≈ 0.9 cm with 2–4 views after
    # resampling); at a quarter of the weight they still help: ≈ 0.7 of that. The
    # previous estimator, side weights on the lateral coordinate only, gave ≈ 1.0×.
    assert err["mean"] > 0.007
    assert err["weighted"] < 0.85 * err["mean"]


def test_weighted_does_not_swap_legs_that_are_a_step_apart(walk) -> None:  # type: ignore[no-untyped-def]
    """A far-side view whose ankles' lateral order is inverted by noise while the feet
    are a step apart along the walk has not swapped them: undoing a "swap" there moved
    the right ankle half a step onto the left one (a six-sensor report lost a step)."""
    rng = np.random.default_rng(5)
    streams = six_sensor_streams(walk, rng, occluded_bias_m=0.0, noise_m=0.005,
                                 inferred_frac=0.0, clocks=False)
    two = [streams[2], streams[3]]  # S3 (left of the walkway) and S4 (right)
    ser, T = two[1].series, np.asarray(two[1].T_world_sensor)
    truth_all = walk_skeleton(walk)
    iL, iR = KINECT_V2.index("AnkleLeft"), KINECT_V2.index("AnkleRight")
    t_true = sample_truth(walk, truth_all, ser.times)
    apart = np.abs(t_true[:, iL, 0] - t_true[:, iR, 0]) > 0.4  # double support
    # S4 sees the left ankle 9 cm to the right (+Y is the walker's left) and the right
    # ankle 9 cm to the left: their lateral order inverted, each still at its own step.
    to_sensor = T[:3, :3].T
    ser.positions[apart, iL] += to_sensor @ np.array([0.0, -0.09, 0.0])
    ser.positions[apart, iR] += to_sensor @ np.array([0.0, 0.09, 0.0])
    fused, _ = integrate_skeletons(two, "weighted", surface_bias_m=0.0, cutoff_hz=None)
    truth = sample_truth(walk, truth_all, fused.times)
    sel = np.abs(truth[:, iL, 0] - truth[:, iR, 0]) > 0.5
    for j in (iL, iR):
        along = np.abs(fused.positions[sel, j, 0] - truth[sel, j, 0])
        assert sel.sum() > 20 and np.nanmax(along) < 0.03, KINECT_V2.joints[j]


def test_weighted_undoes_a_swap_when_the_other_sensor_sees_one_ankle(walk) -> None:  # type: ignore[no-untyped-def]
    """The far ankle is often hidden exactly when the legs cross, where trackers swap
    them: the other sensor, seeing the near ankle alone, is the reference (it was not
    used, and the fused ankles took half the swap: a step 13 cm too long, its placement
    150 ms late)."""
    rng = np.random.default_rng(5)
    streams = six_sensor_streams(walk, rng, occluded_bias_m=0.0, noise_m=0.005,
                                 inferred_frac=0.0, clocks=False)
    two = [streams[2], streams[3]]  # S3 (left of the walkway) and S4 (right)
    legs = [(KINECT_V2.index(f"{p}Left"), KINECT_V2.index(f"{p}Right"))
            for p in ("Knee", "Ankle", "Foot")]
    swapped, seeing_one = two[1].series, two[0].series
    sw = (swapped.times > 3.0) & (swapped.times < 3.25)
    for a, b in legs:
        swapped.positions[sw, a], swapped.positions[sw, b] = (
            swapped.positions[sw, b].copy(), swapped.positions[sw, a].copy())
    hidden = (seeing_one.times > 2.9) & (seeing_one.times < 3.35)
    iL = KINECT_V2.index("AnkleLeft")
    seeing_one.states[hidden, iL] = TrackingState.NOT_TRACKED
    fused, _ = integrate_skeletons(two, "weighted", surface_bias_m=0.0, cutoff_hz=None)
    sel = (fused.times > 3.05) & (fused.times < 3.2)
    truth = sample_truth(walk, walk_skeleton(walk), fused.times)
    for j in (iL, KINECT_V2.index("AnkleRight")):
        err = np.linalg.norm(fused.positions[sel, j] - truth[sel, j], axis=1)
        assert sel.sum() >= 4 and np.nanmax(err) < 0.02, KINECT_V2.joints[j]
