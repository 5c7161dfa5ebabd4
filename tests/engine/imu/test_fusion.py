"""Fused depth/IMU skeleton on the simulated walker: knee flexion vs ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from engine.errors import InputError, InsufficientDataError
from engine.geometry import (
    make_transform,
    quat_angle,
    quat_from_axis_angle,
    quat_from_matrix,
    quat_mul,
    quat_slerp,
    quat_to_matrix,
)
from engine.imu.filter import orientation_filter
from engine.imu.fusion import (
    PAPER_SENSORS,
    delta_quaternions,
    flexion_angles,
    fuse_skeleton,
    joint_rotation,
    ncc,
    plank_calibration,
    rmse,
    select_reference_frame,
)
from engine.sim.imu import ImuNoise, StandingStart, simulate_imu
from engine.sim.walker import Walker, WalkerParams
from engine.skeleton import KINECT_V2, SkeletonSeries, TrackingState

FS = 100.0
# the plank rest lasts 5 s: the filter learns each gyroscope bias there (protocol)
T_PLANK, T_STRAP, T_STILL, T_END = 5.0, 7.0, 10.0, 15.0
YAW_ENU_WORLD = np.deg2rad(35.0)  # the depth world is not aligned with east/north
BONE_OF = {"chest": "trunk"}       # sensor name -> walker bone (others share the name)


def _minjerk(s: np.ndarray) -> np.ndarray:
    return s ** 3 * (10 - 15 * s + 6 * s ** 2)


@pytest.fixture(scope="module")
def scenario() -> dict:
    # the subject stands straight (calibration pose) until T_STILL - 1 s, then walks
    walker = StandingStart(Walker(WalkerParams(), [0.0, 0.0, 0.0], [6.0, 0.5, 0.0],
                                  start_time=T_STILL, seed=3))
    t = np.arange(0.0, T_END, 1.0 / FS)
    frames = walker.bone_frames(t)
    joints = walker.joints(t)
    R_enu_world = quat_to_matrix(quat_from_axis_angle([0, 0, 1], YAW_ENU_WORLD))
    T_enu_world = make_transform(R_enu_world, [0, 0, 0])
    q_plank_world = quat_from_axis_angle([1.0, 0.0, 0.0], np.deg2rad(90.0))  # plank on edge
    rng = np.random.default_rng(7)
    imus, truth_q = {}, {}
    for i, sensor in enumerate(PAPER_SENSORS):
        bone = frames[BONE_OF.get(sensor, sensor)]
        # sensor strapped to the side of the segment, misaligned by a random rotation
        mount_q = quat_from_axis_angle(rng.normal(size=3), rng.uniform(0.2, 1.0))
        T_bs = make_transform(quat_to_matrix(mount_q), [0.0, 0.05, -0.15])
        T_ws = bone @ T_bs
        # plank phase, then a smooth transfer to the body, then the bone's own motion
        q_body0 = quat_from_matrix(T_ws[int(T_STRAP * FS), :3, :3])
        p_plank = np.array([1.0 + 0.1 * i, -1.0, 0.8])
        poses = T_ws.copy()
        for k, tk in enumerate(t):
            if tk < T_PLANK:
                poses[k] = make_transform(quat_to_matrix(q_plank_world), p_plank)
            elif tk < T_STRAP:
                s = _minjerk(np.array((tk - T_PLANK) / (T_STRAP - T_PLANK)))
                q = quat_slerp(q_plank_world, q_body0, s)
                p = (1 - s) * p_plank + s * T_ws[int(T_STRAP * FS), :3, 3]
                poses[k] = make_transform(quat_to_matrix(q), p)
        rec = simulate_imu(t, T_enu_world @ poses, noise=ImuNoise(), rng=100 + i, name=sensor)
        imus[sensor] = rec
        truth_q[sensor] = rec.quat_ref
    # depth skeleton: 30 Hz, Kinect-like joint noise, world frame
    td = np.arange(T_STRAP + 0.5, T_END - 0.1, 1.0 / 30.0)
    Jd = walker.joints(td)
    noisy = Jd + np.random.default_rng(11).normal(0.0, 0.02, Jd.shape)
    depth = SkeletonSeries(td, noisy, np.full(Jd.shape[:2], TrackingState.TRACKED, np.uint8),
                           KINECT_V2)
    return {"t": t, "imus": imus, "depth": depth, "truth_joints": joints,
            "q_plank_world": q_plank_world, "walker": walker, "truth_q": truth_q}


def test_fused_knee_flexion_beats_depth_only(scenario: dict) -> None:
    t, imus, depth = scenario["t"], scenario["imus"], scenario["depth"]
    gyr = np.stack([imus[s].gyr for s in PAPER_SENSORS], axis=1)
    acc = np.stack([imus[s].acc for s in PAPER_SENSORS], axis=1)
    mag = np.stack([imus[s].mag for s in PAPER_SENSORS], axis=1)
    q, _, _ = orientation_filter(gyr, acc, mag, frequency=FS)
    ori = {s: q[:, i] for i, s in enumerate(PAPER_SENSORS)}
    calib = plank_calibration(t, ori, plank_time=T_PLANK - 0.5,
                              q_world_plank=scenario["q_plank_world"])
    fused = fuse_skeleton(depth, t, ori, calib)
    # the reference frame is chosen where the subject stands still
    assert depth.times[fused.reference_index] < T_STILL
    fs = fused.skeleton
    truth = SkeletonSeries(fs.times, scenario["walker"].joints(fs.times),
                           fs.states, KINECT_V2)
    walk = fs.times > T_STILL
    ang_f, ang_t = flexion_angles(fs), flexion_angles(truth)
    depth_truth = SkeletonSeries(depth.times, scenario["walker"].joints(
        depth.times), depth.states, KINECT_V2)
    ang_d, ang_dt = flexion_angles(depth), flexion_angles(depth_truth)
    dwalk = depth.times > T_STILL
    for knee in ("knee_left", "knee_right"):
        e_fused = rmse(ang_f[knee][walk], ang_t[knee][walk])
        e_depth = rmse(ang_d[knee][dwalk], ang_dt[knee][dwalk])
        assert e_fused <= 0.5 * e_depth, (knee, e_fused, e_depth)
        assert e_fused < 4.0
        assert ncc(ang_f[knee][walk], ang_t[knee][walk]) > 0.97
    # torso joint follows the depth skeleton (interpolated), others are carried by IMUs
    sm = KINECT_V2.index("SpineMid")
    assert np.nanmax(np.abs(fs.positions[:, sm] - truth.positions[:, sm])) < 0.1
    knee = KINECT_V2.index("KneeLeft")
    assert np.sqrt(np.nanmean(np.sum((fs.positions[walk, knee]
                                      - truth.positions[walk, knee]) ** 2, axis=1))) < 0.06


def test_plank_calibration_recovers_world_frame(scenario: dict) -> None:
    t, imus = scenario["t"], scenario["imus"]
    # with perfect orientations, calibrated sensors equal their true world orientation
    ori = {s: imus[s].quat_ref for s in PAPER_SENSORS}
    calib = plank_calibration(t, ori, plank_time=1.0, q_world_plank=scenario["q_plank_world"])
    q_world_enu = quat_from_axis_angle([0, 0, 1], -YAW_ENU_WORLD)
    for s in PAPER_SENSORS:
        diff = quat_mul(calib.q_world_earth[s], q_world_enu * np.array([1, -1, -1, -1]))
        assert quat_angle(diff) < 1e-6
        assert calib.spread_deg[s] < 1e-6
    # a sensor that is not on the plank is rejected
    bad = dict(ori)
    bad["thigh_l"] = quat_mul(quat_from_axis_angle([1, 0, 0], 0.6), ori["thigh_l"])
    with pytest.raises(InputError, match="thigh_l"):
        plank_calibration(t, bad, plank_time=1.0)
    with pytest.raises(InputError, match="outside"):
        plank_calibration(t, ori, plank_time=100.0)


def test_joint_rotation_and_deltas() -> None:
    q1 = quat_from_axis_angle([0, 0, 1], np.linspace(0, 1, 50))
    q2 = quat_mul(q1, quat_from_axis_angle([0, 1, 0], np.full(50, 0.4)))
    rel = joint_rotation(q1, q2)
    assert np.allclose(quat_angle(rel), 0.4)
    d = delta_quaternions(q1)
    # composing the increments reproduces the series (eq. 5)
    acc = q1[0]
    for k in range(len(d)):
        acc = quat_mul(acc, d[k])
    assert quat_angle(quat_mul(acc, q1[-1] * [1, -1, -1, -1])) < 1e-9


def test_reference_frame_and_metrics() -> None:
    t = np.arange(0, 4, 1 / 30)
    rng = np.random.default_rng(0)
    P = np.tile(rng.normal(size=(1, 25, 3)), (len(t), 1, 1))
    P += rng.normal(0, 0.05, P.shape) * (np.abs(t - 2.5) > 0.5)[:, None, None]
    sk = SkeletonSeries(t, P, np.full((len(t), 25), 2, np.uint8), KINECT_V2)
    k = select_reference_frame(sk)
    assert abs(t[k] - 2.5) < 0.3
    sk.states[:] = TrackingState.INFERRED
    with pytest.raises(InsufficientDataError):
        select_reference_frame(sk)
    x = np.sin(np.linspace(0, 6, 100))
    assert rmse(x + 1.0, x) == pytest.approx(1.0)
    assert ncc(2 * x + 3, x) == pytest.approx(1.0)
    assert ncc(-x, x) == pytest.approx(-1.0)


@pytest.fixture(scope="module")
def filtered(scenario: dict) -> dict:
    """Our filter's orientations of the scenario's nine IMUs and their plank calibration."""
    t, imus = scenario["t"], scenario["imus"]
    S = list(PAPER_SENSORS)
    q, _, _ = orientation_filter(*(np.stack([getattr(imus[s], k) for s in S], axis=1)
                                   for k in ("gyr", "acc", "mag")), frequency=FS)
    ori = {s: q[:, i] for i, s in enumerate(S)}
    return {"ori": ori, "calib": plank_calibration(t, ori, T_PLANK - 0.5,
                                                   scenario["q_plank_world"])}


def _kinect_depth(walker: object, seed: int) -> SkeletonSeries:
    """Depth skeleton of ``walker`` from the sim's DEFAULT Kinect v2 error model (slow
    fitting errors, surface bias, occlusion, late acquisition), in the world frame; the
    subject walks towards the sensor."""
    from engine.geometry import transform_points
    from engine.sim.rig import SimSensor, sensor_pose
    from engine.sim.skeleton_model import observe_skeletons

    sensor = SimSensor("K", sensor_pose([4.3, 0.2, 0.9], 180.0, 5.0), fps_jitter=0.0)
    td = np.arange(T_STRAP + 0.5, T_END - 0.1, 1.0 / 30.0)
    sk = observe_skeletons(sensor, None, walker,  # type: ignore[arg-type]
                           td, np.random.default_rng(seed))
    return SkeletonSeries(sk.times, transform_points(sensor.T_world_sensor, sk.positions),
                          sk.states, KINECT_V2)


@pytest.mark.parametrize("kinect_seed", [1, 2, 3])
def test_fusion_with_realistic_kinect_errors(scenario: dict, filtered: dict,
                                             kinect_seed: int) -> None:
    """Acceptance (issue 7): with the sim's realistic Kinect errors, the fused knee-flexion
    RMSE is at most half the depth-only RMSE — with the standing-pose calibration.

    The paper's reference-frame method and the all-frames fit keep a constant offset of
    several degrees from the depth tracker's systematic bone-direction errors; the
    standing calibration removes it (to second order), leaving the IMU filter's ~1°."""
    t, walker = scenario["t"], scenario["walker"]
    ori, calib = filtered["ori"], filtered["calib"]
    depth = _kinect_depth(walker, kinect_seed)

    def truth(tt: np.ndarray) -> SkeletonSeries:
        return SkeletonSeries(tt, walker.joints(tt),
                              np.full((len(tt), 25), 2, np.uint8), KINECT_V2)

    ang_d = flexion_angles(depth, tracked_only=True)
    ang_dt = flexion_angles(truth(depth.times))
    seen = (depth.times > T_STILL) & np.isfinite(ang_d["knee_left"]) \
        & np.isfinite(ang_d["knee_right"])
    assert seen.sum() > 45  # at least 1.5 s of walking seen by the depth sensor
    e_depth = {j: rmse(ang_d[j][seen], ang_dt[j][seen]) for j in ang_d}
    errs, nccs = {}, {}
    for fit in ("standing", "all", "reference"):
        fused = fuse_skeleton(depth, t, ori, calib, bone_fit=fit)
        assert fused.warnings == []
        fs = fused.skeleton
        ang_f, ang_t = flexion_angles(fs), flexion_angles(truth(fs.times))
        walk = (fs.times > T_STILL) & (fs.times < depth.times[seen].max())
        errs[fit] = {j: rmse(ang_f[j][walk], ang_t[j][walk]) for j in ang_f}
        nccs[fit] = {j: ncc(ang_f[j][walk], ang_t[j][walk]) for j in ang_f}
    msg = f"fused {errs}, depth-only {e_depth}"
    for j in ("knee_left", "knee_right"):
        # the acceptance bound; the standing calibration leaves only the filter's
        # orientation error (~0.6°, ratios 0.12-0.21 with the sim's default Kinect model)
        assert errs["standing"][j] <= 0.5 * e_depth[j], (j, msg)
        assert errs["standing"][j] < 2.0, (j, msg)
        assert nccs["standing"][j] > 0.99, (j, nccs)
    for j in ("elbow_left", "elbow_right"):
        assert errs["standing"][j] <= 0.5 * e_depth[j], (j, msg)
    # the calibration pose beats fitting the bone vectors to the depth data
    assert np.mean(list(errs["standing"].values())) < np.mean(list(errs["all"].values()))
    assert np.mean(list(errs["all"].values())) < np.mean(list(errs["reference"].values()))


def test_standing_calibration_is_second_order_in_depth_errors(scenario: dict) -> None:
    """With perfect IMU orientations, a grossly biased depth skeleton (every joint shifted
    by its own constant offset of several cm) leaves the fused flexion exact; a
    subject standing with bent knees leaves exactly that bend as offset."""
    from engine.sim.walker import Walker, WalkerParams

    t = scenario["t"]
    for knee_deg in (0.0, 4.0):
        rng = np.random.default_rng(5)
        walker = StandingStart(Walker(WalkerParams(), [0.0, 0.0, 0.0], [6.0, 0.5, 0.0],
                                      start_time=T_STILL, seed=3), knee_flexion_deg=knee_deg)
        frames = walker.bone_frames(t)
        ori = {s: quat_from_matrix(frames[BONE_OF.get(s, s)][:, :3, :3])
               for s in PAPER_SENSORS}
        calib = plank_calibration(t, ori, 1.0)  # sensors = bones, world = ENU
        td = np.arange(T_STRAP, T_END, 1.0 / 30.0)
        # constant bias per joint: 3 cm SD on the legs (a ~6° bone-direction error), 1.5 cm
        # on the shorter arm segments
        sd = np.where(np.isin(np.arange(25), [KINECT_V2.index(n) for n in (
            "HipLeft", "KneeLeft", "AnkleLeft", "HipRight", "KneeRight", "AnkleRight")]),
            0.03, 0.015)
        J = walker.joints(td) + rng.normal(0.0, 1.0, (1, 25, 3)) * sd[:, None]
        J += rng.normal(0.0, 0.005, J.shape)
        depth = SkeletonSeries(td, J, np.full(J.shape[:2], 2, np.uint8), KINECT_V2)
        fused = fuse_skeleton(depth, t, ori, calib)
        assert fused.warnings == []
        fs = fused.skeleton
        ang_f = flexion_angles(fs)
        ang_t = flexion_angles(SkeletonSeries(fs.times, walker.joints(fs.times), fs.states,
                                              KINECT_V2))
        walk = fs.times > T_STILL
        for j in ("knee_left", "knee_right"):
            err = ang_f[j][walk] - ang_t[j][walk]
            assert np.sqrt(np.mean((np.abs(err) - knee_deg) ** 2)) < 0.2 + 0.1 * knee_deg, \
                (knee_deg, j)
        for j in ("elbow_left", "elbow_right"):
            assert rmse(ang_f[j][walk], ang_t[j][walk]) < 0.3
        # the all-frames fit does not have this property: a constant bias stays
        fa = fuse_skeleton(depth, t, ori, calib, bone_fit="all").skeleton
        if knee_deg == 0.0:
            assert max(rmse(flexion_angles(fa)[j][walk], ang_t[j][walk])
                       for j in ("knee_left", "knee_right")) > 1.0


def test_bent_standing_pose_warns(scenario: dict, filtered: dict) -> None:
    """A reference pose with bent knees is not used as 'straight': warning, fallback."""
    depth = scenario["depth"]
    J = depth.positions.copy()
    ki, ai = KINECT_V2.index("KneeLeft"), KINECT_V2.index("AnkleLeft")
    J[:, ai] = J[:, ki] + (J[:, ai] - J[:, ki]) @ quat_to_matrix(
        quat_from_axis_angle([0, 1, 0], np.deg2rad(50.0))).T
    bent = SkeletonSeries(depth.times, J, depth.states, KINECT_V2)
    fused = fuse_skeleton(bent, scenario["t"], filtered["ori"], filtered["calib"])
    assert len(fused.warnings) == 1 and "hip-ankle_left" in fused.warnings[0]
    assert np.isfinite(fused.skeleton.positions[:, ai]).all()
