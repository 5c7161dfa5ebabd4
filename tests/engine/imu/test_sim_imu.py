"""Simulated IMUs: ideal sensors reproduce the motion they were generated from."""

from __future__ import annotations

import numpy as np
import pytest

from engine.errors import InputError
from engine.geometry import (
    make_transform,
    quat_angle,
    quat_conj,
    quat_from_axis_angle,
    quat_from_rotvec,
    quat_mul,
    quat_rotate,
    quat_to_matrix,
)
from engine.imu.fusion import PAPER_SENSORS
from engine.sim.imu import NO_NOISE, ImuNoise, simulate_imu, simulate_walker_imus
from engine.sim.walker import Walker, WalkerParams

G = 9.80665


def test_ideal_sensor_on_a_pendulum() -> None:
    # a 0.5 m leg swinging about the world x axis, the sensor at its end
    fs = 500.0
    t = np.arange(0.0, 4.0, 1 / fs)
    theta = 0.6 * np.sin(2 * np.pi * 0.8 * t)
    q = quat_from_axis_angle([1.0, 0.0, 0.0], theta)
    L = 0.5
    poses = np.stack([make_transform(quat_to_matrix(qq), quat_rotate(qq, [0, 0, -L]))
                      for qq in q])
    rec = simulate_imu(t, poses, noise=NO_NOISE)
    # gyro = angular rate about sensor x (= world x for this motion)
    w_true = 0.6 * 2 * np.pi * 0.8 * np.cos(2 * np.pi * 0.8 * (t - 0.5 / fs))
    assert np.allclose(rec.gyr[1:, 0], w_true[1:], atol=1e-3)
    assert np.allclose(rec.gyr[:, 1:], 0.0, atol=1e-9)
    # integrating the gyro reproduces the truth (the filter's own scheme)
    qi = q[0].copy()
    for k in range(1, len(t)):
        qi = quat_mul(qi, quat_from_rotvec(rec.gyr[k] / fs))
    assert quat_angle(quat_mul(qi, quat_conj(q[-1]))) < 1e-6
    # accelerometer: centripetal + tangential + gravity, in the sensor frame
    thd = np.gradient(theta, t)
    thdd = np.gradient(thd, t)
    a_expect = np.stack([np.zeros_like(t), L * thdd, G * np.cos(theta) + L * thd ** 2], 1)
    a_expect[:, 1] += G * np.sin(theta)
    mid = slice(5, -5)
    assert np.allclose(rec.acc[mid], a_expect[mid], atol=0.05)
    # magnetometer: the earth field seen from the sensor, norm preserved
    assert np.allclose(np.linalg.norm(rec.mag, axis=1), np.hypot(20.0, 44.0), atol=1e-9)


def test_noise_model_statistics() -> None:
    t = np.arange(0.0, 200.0, 0.01)
    poses = np.tile(np.eye(4), (len(t), 1, 1))
    noise = ImuNoise(gyr_noise=0.01, gyr_bias=0.0, gyr_bias_walk=0.001, acc_noise=0.1,
                     mag_noise=0.5)
    rec = simulate_imu(t, poses, noise=noise, rng=1)
    bias = rec.meta["true_gyr_bias"]
    assert np.std(rec.gyr - bias) == pytest.approx(0.01, rel=0.05)
    assert np.std(rec.acc[:, 0]) == pytest.approx(0.1, rel=0.05)
    # random walk: variance grows linearly, σ(200 s) = 0.001·√200
    assert np.std(bias[-1] - bias[0]) < 5 * 0.001 * np.sqrt(200)
    assert np.max(np.abs(np.diff(bias, axis=0))) < 10 * 0.001 * np.sqrt(0.01)
    with pytest.raises(InputError, match="uniformly"):
        simulate_imu(np.r_[t[:10], t[12:20]], poses[:18])
    with pytest.raises(InputError, match="shape"):
        simulate_imu(t[:10], poses[:9])


def test_walker_imus() -> None:
    walker = Walker(WalkerParams(), [0.0, 0.0, 0.0], [6.0, 0.0, 0.0])
    t = np.arange(1.0, 3.0, 1 / 256)
    recs = simulate_walker_imus(walker, t, noise=NO_NOISE)
    assert set(recs) == set(PAPER_SENSORS)
    frames = walker.bone_frames(t)
    R = quat_to_matrix(recs["shank_l"].quat_ref)
    assert np.allclose(R, frames["shank_l"][:, :3, :3], atol=1e-9)
    # mean specific force over a walk is about gravity (no net vertical acceleration)
    a_world = quat_rotate(recs["chest"].quat_ref, recs["chest"].acc)
    assert np.mean(a_world[:, 2]) == pytest.approx(G, abs=0.3)


def test_standing_start_and_jumps() -> None:
    """The calibration pose: limbs straight and hanging, joints consistent with the bone
    frames, continuous into the walk; jumps lift the whole body."""
    from engine.imu.fusion import flexion_angles
    from engine.sim.imu import Jumping, StandingStart, jump_height
    from engine.skeleton import KINECT_V2, SkeletonSeries

    w = Walker(WalkerParams(), [0.0, 0.0, 0.0], [6.0, 0.0, 0.0], start_time=5.0, seed=1)
    s = StandingStart(w, knee_flexion_deg=4.0)
    t = np.array([0.0, 3.9, 4.5, 4.999, 5.0, 5.5])
    J = s.joints(t)
    ang = flexion_angles(SkeletonSeries(t, J, np.full((len(t), 25), 2, np.uint8), KINECT_V2))
    assert ang["knee_left"][:2] == pytest.approx(4.0, abs=1e-6)
    assert ang["elbow_right"][:2] == pytest.approx(0.0, abs=1e-6)
    assert np.allclose(J[3], w.joints([5.0])[0], atol=1e-3)  # blends into the start pose
    assert np.allclose(J[4:], w.joints(t[4:]))
    i = KINECT_V2.index
    shank = J[0, i("KneeLeft")] - J[0, i("AnkleLeft")]
    assert np.degrees(np.arccos(shank[2] / np.linalg.norm(shank))) == pytest.approx(2.0, abs=0.01)
    F = s.bone_frames(t)
    for bone, a, b in (("thigh_r", "HipRight", "KneeRight"), ("forearm_l", "ElbowLeft",
                                                             "WristLeft")):
        assert np.allclose(F[bone][:, :3, 3], J[:, i(a)])
        z = F[bone][:, :3, 2]
        d = J[:, i(a)] - J[:, i(b)]
        assert np.allclose(z, d / np.linalg.norm(d, axis=1, keepdims=True), atol=1e-9)
    jumps = Jumping(s, [1.0])
    tj = np.arange(0.0, 2.5, 0.01)
    dz = jump_height(tj, [1.0])
    assert dz.max() > 0.4 and dz[0] == 0.0 and dz[-1] == pytest.approx(0.0, abs=1e-9)
    assert np.allclose(jumps.joints(tj)[..., 2] - s.joints(tj)[..., 2], dz[:, None])
    A, _, _ = jumps.capsule_segments(tj)
    A0, _, _ = s.capsule_segments(tj)
    assert np.allclose(A[..., 2] - A0[..., 2], dz[:, None])
