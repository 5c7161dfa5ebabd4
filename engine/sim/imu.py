"""Simulated body-worn IMUs from bone poses over time (ground truth for the fusion tests).

A sensor is rigidly mounted on a bone (``T_bone_sensor``). From the bone's world poses
``T_world_bone(t)`` (world: x east, y north, z up, m) it produces what a real IMU would
measure in its own frame:

* gyroscope: the sensor's angular velocity, plus white noise and a bias that starts at a
  random value and performs a random walk;
* accelerometer: specific force ``Rᵀ (p̈ + g·ẑ)`` (gravity reaction plus linear
  acceleration of the sensor origin), plus white noise;
* magnetometer: ``Rᵀ (B_earth + B_disturbance(t))`` plus white noise, in µT.

The gyroscope sample ``k`` is the mean rate over ``[t_{k-1}, t_k]`` (rotation vector of
``q_{k-1}* ⊗ q_k`` over the step), exactly what a filter integrating from sample ``k−1`` to
``k`` needs; the truth orientation is returned with the recording (``quat_ref``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.errors import InputError
from engine.geometry import quat_conj, quat_from_matrix, quat_mul, quat_rotate, quat_to_rotvec
from engine.imu.io import ImuRecording

FloatArray = NDArray[np.float64]
G = 9.80665
#: Earth field (µT) in ENU for a mid-European site: 20 µT north, 44 µT down (dip ≈ 66°).
EARTH_FIELD_ENU: tuple[float, float, float] = (0.0, 20.0, -44.0)


@dataclass(frozen=True)
class ImuNoise:
    """Sensor error model (defaults: a consumer MEMS IMU such as the x-IMU).

    Attributes:
        gyr_noise: white-noise standard deviation per sample, rad/s.
        gyr_bias: standard deviation of the initial per-axis bias, rad/s.
        gyr_bias_walk: bias random-walk density, rad/s/√s.
        acc_noise: white-noise standard deviation per sample, m/s².
        mag_noise: white-noise standard deviation per sample, µT.
    """

    gyr_noise: float = np.deg2rad(0.3)
    gyr_bias: float = np.deg2rad(0.5)
    gyr_bias_walk: float = np.deg2rad(0.01)
    acc_noise: float = 0.05
    mag_noise: float = 0.3


NO_NOISE = ImuNoise(0.0, 0.0, 0.0, 0.0, 0.0)


def simulate_imu(
    times: ArrayLike,
    T_world_bone: ArrayLike,
    T_bone_sensor: ArrayLike | None = None,
    *,
    noise: ImuNoise = ImuNoise(),
    earth_field: ArrayLike = EARTH_FIELD_ENU,
    mag_disturbance: ArrayLike | None = None,
    rng: np.random.Generator | int | None = 0,
    name: str = "sim",
) -> ImuRecording:
    """Simulate one IMU mounted on a moving bone.

    Args:
        times: ``(T,)`` s, uniformly spaced.
        T_world_bone: ``(T, 4, 4)`` bone poses in the ENU world frame (m).
        T_bone_sensor: ``(4, 4)`` mounting of the sensor on the bone (identity by default).
        noise: sensor error model (:data:`NO_NOISE` for ideal sensors).
        earth_field: Earth magnetic field in world coordinates, µT.
        mag_disturbance: ``(T, 3)`` extra world-frame field (µT), e.g. near a metal object.
        rng: random generator or seed.
        name: sensor name stored in the recording.

    Returns:
        An :class:`ImuRecording` in SI units whose ``quat_ref`` holds the true
        sensor-to-ENU orientation and ``meta["true_gyr_bias"]`` the bias, ``(T, 3)``.

    Raises:
        InputError: shapes or time stamps are unusable.
    """
    t = np.asarray(times, dtype=float)
    Twb = np.asarray(T_world_bone, dtype=float)
    if Twb.shape != (len(t), 4, 4):
        raise InputError(f"T_world_bone must have shape ({len(t)}, 4, 4), got {Twb.shape}")
    if len(t) < 3:
        raise InputError("need at least three poses to differentiate")
    dts = np.diff(t)
    dt = float(np.mean(dts))
    if np.any(dts <= 0) or np.max(np.abs(dts - dt)) > 1e-6 * max(dt, 1e-9) + 1e-9:
        raise InputError("times must be uniformly spaced and increasing")
    Tbs = np.eye(4) if T_bone_sensor is None else np.asarray(T_bone_sensor, dtype=float)
    Tws = Twb @ Tbs
    q = quat_from_matrix(Tws[:, :3, :3])
    # continuous sign so that consecutive quaternions are close
    flip = np.cumsum(np.r_[0, np.sum(q[1:] * q[:-1], axis=1) < 0]) % 2 == 1
    q[flip] *= -1
    p = Tws[:, :3, 3]
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)

    rel = quat_mul(quat_conj(q[:-1]), q[1:])
    w = np.empty((len(t), 3))
    w[1:] = quat_to_rotvec(rel) / dt
    w[0] = w[1]
    acc_world = np.gradient(np.gradient(p, t, axis=0), t, axis=0)
    acc_world[:, 2] += G
    acc = quat_rotate(quat_conj(q), acc_world)
    field_w = np.broadcast_to(np.asarray(earth_field, dtype=float), (len(t), 3)).copy()
    if mag_disturbance is not None:
        md = np.asarray(mag_disturbance, dtype=float)
        if md.shape != (len(t), 3):
            raise InputError(f"mag_disturbance must have shape ({len(t)}, 3), got {md.shape}")
        field_w += md
    mag = quat_rotate(quat_conj(q), field_w)

    bias = gen.normal(0.0, noise.gyr_bias, 3) + np.cumsum(
        gen.normal(0.0, noise.gyr_bias_walk * np.sqrt(dt), (len(t), 3)), axis=0)
    gyr = w + bias + gen.normal(0.0, noise.gyr_noise, (len(t), 3))
    acc = acc + gen.normal(0.0, noise.acc_noise, (len(t), 3))
    mag = mag + gen.normal(0.0, noise.mag_noise, (len(t), 3))
    return ImuRecording(
        time=t.copy(), gyr=gyr, acc=acc, mag=mag, frequency=1.0 / dt, name=name, quat_ref=q,
        meta={"format": "simulated", "gyr_unit": "rad/s", "acc_unit": "m/s2",
              "mag_unit": "uT", "true_gyr_bias": bias, "true_position": p})


def simulate_imus(
    times: ArrayLike,
    bone_frames: dict[str, FloatArray],
    mounts: dict[str, FloatArray] | None = None,
    *,
    noise: ImuNoise = ImuNoise(),
    earth_field: ArrayLike = EARTH_FIELD_ENU,
    seed: int = 0,
) -> dict[str, ImuRecording]:
    """Simulate one IMU per bone (e.g. the walker's ``bone_frames(t)``).

    Args:
        times: ``(T,)`` s.
        bone_frames: bone name -> ``(T, 4, 4)`` world poses.
        mounts: bone name -> ``T_bone_sensor`` (identity where missing).
        noise: sensor error model shared by all sensors (independent draws).
        earth_field: Earth field in world coordinates, µT.
        seed: base random seed; sensor ``i`` uses ``seed + i``.
    """
    mounts = mounts or {}
    return {
        bone: simulate_imu(times, frames, mounts.get(bone), noise=noise,
                           earth_field=earth_field, rng=seed + i, name=bone)
        for i, (bone, frames) in enumerate(bone_frames.items())
    }


#: The seed paper's nine sensors (``engine.imu.fusion.PAPER_SENSORS``) -> walker bone.
WALKER_BONE_OF_SENSOR: dict[str, str] = {
    "chest": "trunk",
    "upperarm_l": "upperarm_l", "forearm_l": "forearm_l",
    "upperarm_r": "upperarm_r", "forearm_r": "forearm_r",
    "thigh_l": "thigh_l", "shank_l": "shank_l",
    "thigh_r": "thigh_r", "shank_r": "shank_r",
}


def simulate_walker_imus(
    walker: Any,
    times: ArrayLike,
    mounts: dict[str, FloatArray] | None = None,
    *,
    sensors: dict[str, str] | None = None,
    noise: ImuNoise = ImuNoise(),
    earth_field: ArrayLike = EARTH_FIELD_ENU,
    seed: int = 0,
) -> dict[str, ImuRecording]:
    """The paper's nine IMUs worn by a simulated walker (``engine.sim.walker.Walker``).

    Args:
        walker: anything with ``bone_frames(t) -> dict[bone, (T, 4, 4)]`` (world = ENU).
        times: ``(T,)`` s, uniformly spaced (e.g. 256 Hz as the x-IMUs of the paper).
        mounts: sensor name -> ``T_bone_sensor`` (identity where missing).
        sensors: sensor name -> walker bone (default :data:`WALKER_BONE_OF_SENSOR`).
        noise, earth_field, seed: as in :func:`simulate_imus`.

    Returns:
        sensor name -> recording (with ``quat_ref`` ground truth).
    """
    smap = sensors or WALKER_BONE_OF_SENSOR
    frames = walker.bone_frames(np.asarray(times, dtype=float))
    missing = [b for b in smap.values() if b not in frames]
    if missing:
        raise InputError(f"walker has no bone(s) {missing}; it has {sorted(frames)}")
    mounts = mounts or {}
    return {
        name: simulate_imu(times, frames[bone], mounts.get(name), noise=noise,
                           earth_field=earth_field, rng=seed + i, name=name)
        for i, (name, bone) in enumerate(smap.items())
    }
