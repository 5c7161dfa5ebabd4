"""End-to-end IMU session on the simulated walker: auto plank, fusion, CSV export."""

from __future__ import annotations

import numpy as np
import pytest

from engine.errors import InputError
from engine.imu.fusion import flexion_angles, rmse
from engine.imu.pipeline import angles_csv, process_imu_session
from engine.imu.sync import shift_recording
from engine.skeleton import KINECT_V2, SkeletonSeries
from tests.engine.imu.test_fusion import T_PLANK, T_STILL, T_STRAP, scenario  # noqa: F401


def test_session_end_to_end(scenario: dict) -> None:  # noqa: F811
    res = process_imu_session(scenario["imus"], scenario["depth"], synchronise=False,
                              q_world_plank=scenario["q_plank_world"])
    # the plank pose is found automatically (all sensors resting with equal tilt)
    assert 0.5 < res.calibration.time < T_PLANK
    fs = res.fused.skeleton
    truth = SkeletonSeries(fs.times, scenario["walker"].joints(fs.times),
                           fs.states, KINECT_V2)
    ang_t = flexion_angles(truth)
    walk = fs.times > T_STILL
    for j in ("knee_left", "knee_right"):
        assert rmse(res.angles_fused[j][walk], ang_t[j][walk]) < 4.0
    text = angles_csv(res)
    lines = text.strip().splitlines()
    assert lines[0].startswith("time_s,knee_left_fused_deg,knee_left_depth_deg")
    assert len(lines) == len(fs.times) + 1
    row = lines[len(lines) // 2].split(",")
    assert len(row) == 9 and row[1] != "" and row[2] != ""
    # the fused skeleton exists only while the depth skeleton does
    assert fs.times[0] >= T_STRAP


def test_session_input_errors(scenario: dict) -> None:  # noqa: F811
    imus = dict(scenario["imus"])
    with pytest.raises(InputError, match="unknown sensor"):
        process_imu_session({**imus, "knee": imus["chest"]}, scenario["depth"],
                            synchronise=False)
    imus.pop("chest")
    with pytest.raises(InputError, match="chest"):
        process_imu_session(imus, scenario["depth"], synchronise=False)


def test_session_with_jump_sync() -> None:
    """Full protocol: plank, strapping, five jumps, standing, walking; every IMU clock and
    the depth clock disagree. Sync, plank, fusion and angles run in one call."""
    from engine.geometry import (
        make_transform,
        quat_from_axis_angle,
        quat_from_matrix,
        quat_slerp,
        quat_to_matrix,
    )
    from engine.imu.fusion import PAPER_SENSORS
    from engine.sim.imu import StandingStart, simulate_imu
    from engine.sim.walker import Walker, WalkerParams
    from engine.skeleton import TrackingState
    from tests.engine.imu.test_sync import _height

    fs, t_jump0, t_walk, t_end = 100.0, 5.0, 15.0, 19.0
    # stands straight after the jumps (calibration pose), walks from t_walk
    walker = StandingStart(Walker(WalkerParams(), [0.0, 0.0, 0.0], [6.0, 0.3, 0.0],
                                  start_time=t_walk, seed=5))
    t = np.arange(0.0, t_end, 1 / fs)
    tw = t
    dz = np.where(t >= t_jump0, _height(t - t_jump0) - 1.0, 0.0)  # whole-body jumps
    frames = walker.bone_frames(tw)
    q_plank = quat_from_axis_angle([0.0, 1.0, 0.0], 0.3)
    offsets = {}
    recs = {}
    rng = np.random.default_rng(4)
    for i, sensor in enumerate(PAPER_SENSORS):
        bone = frames["trunk" if sensor == "chest" else sensor].copy()
        bone[:, 2, 3] += dz
        T_bs = make_transform(quat_to_matrix(quat_from_axis_angle(rng.normal(size=3), 0.5)),
                              [0.0, 0.04, -0.1])
        T_ws = bone @ T_bs
        k0 = int(t_jump0 * fs)
        q_body = quat_from_matrix(T_ws[k0, :3, :3])
        p_plank = np.array([1.0, -1.0 + 0.08 * i, 0.8])
        for k in range(k0):
            if t[k] < 3.0:
                q, p = q_plank, p_plank
            else:
                s = (t[k] - 3.0) / 2.0
                s = s ** 3 * (10 - 15 * s + 6 * s ** 2)
                q, p = quat_slerp(q_plank, q_body, s), (1 - s) * p_plank + s * T_ws[k0, :3, 3]
            T_ws[k] = make_transform(quat_to_matrix(q), p)
        rec = simulate_imu(t, T_ws, rng=50 + i, name=sensor)
        offsets[sensor] = float(rng.uniform(-2.0, 2.0))
        recs[sensor] = shift_recording(rec, -offsets[sensor])  # the IMU's own clock
    td = np.arange(t_jump0 + 0.3, t_end - 0.1, 1 / 30)
    J = walker.joints(td)
    J[:, :, 2] += np.where(td >= t_jump0, _height(td - t_jump0) - 1.0, 0.0)[:, None]
    J += np.random.default_rng(9).normal(0, 0.01, J.shape)
    depth = SkeletonSeries(td, J, np.full(J.shape[:2], TrackingState.TRACKED, np.uint8),
                           KINECT_V2)

    res = process_imu_session(recs, depth, q_world_plank=q_plank)
    assert res.sync is not None
    for sensor, off in offsets.items():
        # waveform matching: a few ms (the 30 Hz landing peaks alone are ~15 ms off)
        assert res.sync.offsets[sensor] == pytest.approx(off, abs=0.005)
    assert res.calibration.time < 3.0
    fsk = res.fused.skeleton
    walk = fsk.times > t_walk
    truth = SkeletonSeries(fsk.times, walker.joints(fsk.times),
                           fsk.states, KINECT_V2)
    ang_t = flexion_angles(truth)
    for j in ("knee_left", "knee_right"):
        assert rmse(res.angles_fused[j][walk], ang_t[j][walk]) < 4.0


def _protocol(seed: int, t_walk: float = 14.0, t_end: float = 18.0) -> dict:
    """Seed-002 protocol on a simulated subject: IMUs on a plank (0-3 s), strapped on
    (3-5 s), five jumps (from 5 s), standing straight, walking from ``t_walk`` towards
    +x; IMU clocks offset by up to ±2 s."""
    from engine.geometry import (
        make_transform,
        quat_from_axis_angle,
        quat_from_matrix,
        quat_slerp,
        quat_to_matrix,
    )
    from engine.imu.fusion import PAPER_SENSORS
    from engine.sim.imu import WALKER_BONE_OF_SENSOR, Jumping, StandingStart, simulate_imu
    from engine.sim.walker import Walker, WalkerParams

    fs, t_jump0 = 100.0, 5.0
    subject = Jumping(StandingStart(Walker(WalkerParams(), [0.0, 0.0, 0.0], [6.0, 0.3, 0.0],
                                           start_time=t_walk, seed=seed)),
                      t_jump0 + np.array([0.0, 1.3, 2.5, 3.9, 5.1]))
    t = np.arange(0.0, t_end, 1 / fs)
    frames = subject.bone_frames(t)
    q_plank = quat_from_axis_angle([0.0, 1.0, 0.0], 0.3)
    rng = np.random.default_rng(seed)
    recs, offsets = {}, {}
    k0 = int(t_jump0 * fs)
    for i, sensor in enumerate(PAPER_SENSORS):
        T_bs = make_transform(quat_to_matrix(quat_from_axis_angle(rng.normal(size=3), 0.5)),
                              [0.0, 0.04, -0.1])
        T_ws = frames[WALKER_BONE_OF_SENSOR[sensor]] @ T_bs
        q_body = quat_from_matrix(T_ws[k0, :3, :3])
        p_plank = np.array([1.0, -1.0 + 0.08 * i, 0.8])
        for k in range(k0):
            s = float(np.clip((t[k] - 3.0) / 2.0, 0.0, 1.0))
            s = s ** 3 * (10 - 15 * s + 6 * s ** 2)
            T_ws[k] = make_transform(quat_to_matrix(quat_slerp(q_plank, q_body, s)),
                                     (1 - s) * p_plank + s * T_ws[k0, :3, 3])
        rec = simulate_imu(t, T_ws, rng=seed * 100 + i, name=sensor)
        offsets[sensor] = float(rng.uniform(-2.0, 2.0))
        recs[sensor] = shift_recording(rec, -offsets[sensor])
    return {"recs": recs, "offsets": offsets, "subject": subject, "q_plank": q_plank,
            "t_walk": t_walk, "t_end": t_end}


@pytest.mark.parametrize("seed", [1, 2])
def test_session_end_to_end_with_default_kinect_model(seed: int) -> None:
    """Acceptance (issue 7), whole chain: jump sync, plank, standing-pose calibration,
    fusion — the depth skeleton from the sim's default Kinect v2 error model (sensor 4 m
    in front of the subject). Fused knee-flexion RMSE ≤ half the depth-only RMSE."""
    from engine.geometry import transform_points
    from engine.sim.rig import SimSensor, sensor_pose
    from engine.sim.skeleton_model import observe_skeletons

    p = _protocol(seed)
    subject = p["subject"]
    sensor = SimSensor("K", sensor_pose([4.0, 0.3, 0.9], 180.0, 5.0), fps_jitter=0.0)
    td = np.arange(4.0, p["t_end"] - 0.1, 1 / 30)
    sk = observe_skeletons(sensor, None, subject, td,  # type: ignore[arg-type]
                           np.random.default_rng(seed))
    depth = SkeletonSeries(sk.times, transform_points(sensor.T_world_sensor, sk.positions),
                           sk.states, KINECT_V2)
    res = process_imu_session(p["recs"], depth, q_world_plank=p["q_plank"])
    for s, off in p["offsets"].items():
        assert res.sync is not None and res.sync.offsets[s] == pytest.approx(off, abs=0.015)
    assert res.warnings == []
    fs = res.fused.skeleton
    ang_t = flexion_angles(SkeletonSeries(fs.times, subject.joints(fs.times), fs.states,
                                          KINECT_V2))
    ang_dt = flexion_angles(SkeletonSeries(depth.times, subject.joints(depth.times),
                                           depth.states, KINECT_V2))
    seen = (depth.times > p["t_walk"]) & np.isfinite(res.angles_depth["knee_left"]) \
        & np.isfinite(res.angles_depth["knee_right"])
    assert seen.sum() > 45
    walk = (fs.times > p["t_walk"]) & (fs.times < depth.times[seen].max())
    for j in ("knee_left", "knee_right"):
        e_fused = rmse(res.angles_fused[j][walk], ang_t[j][walk])
        e_depth = rmse(res.angles_depth[j][seen], ang_dt[j][seen])
        assert e_fused <= 0.5 * e_depth, (j, e_fused, e_depth)
        assert e_fused < 2.0, (j, e_fused, e_depth)
