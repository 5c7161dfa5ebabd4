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
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.errors import InputError
from engine.geometry import (
    quat_conj,
    quat_from_axis_angle,
    quat_from_matrix,
    quat_mul,
    quat_rotate,
    quat_slerp,
    quat_to_matrix,
    quat_to_rotvec,
)
from engine.imu.io import ImuRecording
from engine.wording import named

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

    Returns:
        Bone name -> recording (SI units, time first axis) with the true sensor-to-ENU
        orientation in ``quat_ref``.
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
        raise InputError(f"walker has no {named('bone', missing)}; it has {sorted(frames)}")
    mounts = mounts or {}
    return {
        name: simulate_imu(times, frames[bone], mounts.get(name), noise=noise,
                           earth_field=earth_field, rng=seed + i, name=name)
        for i, (name, bone) in enumerate(smap.items())
    }


def _rot_between(a: FloatArray, b: FloatArray) -> FloatArray:
    """Smallest rotation matrix turning unit vector ``a`` onto unit vector ``b``."""
    v = np.cross(a, b)
    s, c = float(np.linalg.norm(v)), float(a @ b)
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        # opposite vectors: half turn about any axis perpendicular to a
        p = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        return np.asarray(quat_to_matrix(quat_from_axis_angle(p, np.pi)))
    return np.asarray(quat_to_matrix(quat_from_axis_angle(v, np.arctan2(s, c))))


class StandingStart:
    """A simulated walker who first stands upright, limbs straight, then starts walking.

    The calibration pose of seed 002 (Fig. 1b): the subject stands still facing the
    Kinect, every limb bone pointing towards the ground — knees and elbows extended, arms
    hanging at the sides (slightly abducted so that they clear the trunk). Before
    ``walker.start_time - blend_s`` the subject holds that pose at the walker's start
    position and heading; over the next ``blend_s`` seconds every limb segment turns
    (minimum-jerk slerp, proximal joints first) into the walker's start pose, and from
    ``start_time`` on it is the walker itself.

    It offers what the simulators need from a walker — :meth:`joints`,
    :meth:`bone_frames`, :meth:`capsule_segments` (so ``observe_skeletons`` sees the same
    body) — with joints and bone frames consistent at every time, so simulated IMUs and
    the simulated depth skeleton agree.

    Args:
        walker: an ``engine.sim.walker.Walker``.
        blend_s: duration of the transition from standing into the start pose, s.
        arm_abduction_deg: outward tilt of the hanging arms.
        knee_flexion_deg: knee flexion held while standing (0 = fully extended; real
            subjects asked to stand straight keep a few degrees).
        elbow_flexion_deg: elbow flexion held while standing (forearm forwards).
    """

    _LIMBS = (  # (bone, proximal joint, distal joint, parent bone, joints carried along)
        ("thigh_l", "HipLeft", "KneeLeft", None, ()),
        ("shank_l", "KneeLeft", "AnkleLeft", "thigh_l", ("FootLeft",)),
        ("thigh_r", "HipRight", "KneeRight", None, ()),
        ("shank_r", "KneeRight", "AnkleRight", "thigh_r", ("FootRight",)),
        ("upperarm_l", "ShoulderLeft", "ElbowLeft", None, ()),
        ("forearm_l", "ElbowLeft", "WristLeft", "upperarm_l",
         ("HandLeft", "HandTipLeft", "ThumbLeft")),
        ("upperarm_r", "ShoulderRight", "ElbowRight", None, ()),
        ("forearm_r", "ElbowRight", "WristRight", "upperarm_r",
         ("HandRight", "HandTipRight", "ThumbRight")),
    )
    #: bones carried rigidly by a limb segment: bone -> segment
    _CHILD_BONES: ClassVar[dict[str, str]] = {
        "foot_l": "shank_l", "foot_r": "shank_r", "hand_l": "forearm_l", "hand_r": "forearm_r"}

    def __init__(self, walker: Any, blend_s: float = 1.0, arm_abduction_deg: float = 8.0,
                 knee_flexion_deg: float = 0.0, elbow_flexion_deg: float = 0.0) -> None:
        from engine.skeleton import KINECT_V2

        if blend_s <= 0:
            raise InputError("blend_s must be positive")
        self.walker = walker
        self.start_time = float(walker.start_time)
        self.blend_s = float(blend_s)
        self._names = list(KINECT_V2.joints)
        ix = {n: i for i, n in enumerate(self._names)}
        self._ix = ix
        t0 = np.array([self.start_time])
        J = np.asarray(walker.joints(t0))[0]
        F = {k: np.asarray(v)[0] for k, v in walker.bone_frames(t0).items()}
        A, B, _ = walker.capsule_segments(t0)
        self._J, self._F, self._A, self._B = J, F, np.asarray(A)[0], np.asarray(B)[0]
        fwd = F["pelvis"][:3, 0].copy()
        fwd[2] = 0.0
        fwd /= np.linalg.norm(fwd)
        left = np.cross([0.0, 0.0, 1.0], fwd)
        # the legs straight under the hips, feet at the stance foot's height
        kf, ef = np.deg2rad(knee_flexion_deg), np.deg2rad(elbow_flexion_deg)
        leg = (np.linalg.norm(J[ix["HipLeft"]] - J[ix["KneeLeft"]]) + np.linalg.norm(
            J[ix["KneeLeft"]] - J[ix["AnkleLeft"]])) * np.cos(0.5 * kf)
        ankle_z = min(J[ix["AnkleLeft"], 2], J[ix["AnkleRight"], 2])
        self._lift = float(ankle_z + leg - 0.5 * (J[ix["HipLeft"], 2] + J[ix["HipRight"], 2]))
        down = np.array([0.0, 0.0, -1.0])
        ab = np.deg2rad(arm_abduction_deg)
        # standing rotation of each limb segment: the smallest turn of its start-pose
        # frame that makes the bone point down (arms tilted outwards)
        self._q_stand: dict[str, FloatArray] = {}
        self._q_start: dict[str, FloatArray] = {}
        for bone, a, b, _, _ in self._LIMBS:
            u = J[ix[b]] - J[ix[a]]
            u /= np.linalg.norm(u)
            side = 1.0 if bone.endswith("_l") else -1.0
            # flexion turns a segment about the subject's left axis: positive angles move
            # its distal end backwards (knee flexed: thigh forwards, shank backwards)
            tilt = {"thi": -0.5 * kf, "sha": 0.5 * kf, "upp": 0.0, "for": -ef}[bone[:3]]
            d = down if bone[:3] in ("thi", "sha") else (
                np.cos(ab) * down + np.sin(ab) * side * left)
            d = quat_rotate(quat_from_axis_angle(left, tilt), d)
            R = _rot_between(u, d) @ F[bone][:3, :3]
            self._q_stand[bone] = quat_from_matrix(R)
            self._q_start[bone] = quat_from_matrix(F[bone][:3, :3])
        # capsule end points that are not joints (heel, toe) move with a limb segment
        caps = walker.capsules
        self._cap_ends: list[tuple[str, str]] = []
        for c in caps:
            for e in (c.a, c.b):
                if e in ix:
                    self._cap_ends.append(("joint", e))
                else:
                    self._cap_ends.append(("shank_l" if e.endswith("Left") else "shank_r",
                                           "Ankle" + ("Left" if e.endswith("Left")
                                                      else "Right")))

    def _standing(self, t: FloatArray) -> tuple[FloatArray, dict[str, FloatArray],
                                                 FloatArray, FloatArray]:
        """Joints, bone frames and capsule ends at times before ``start_time``."""
        ix, J, F = self._ix, self._J, self._F
        s = np.clip((t - (self.start_time - self.blend_s)) / self.blend_s, 0.0, 1.0)
        s = s ** 3 * (10 - 15 * s + 6 * s ** 2)
        n = len(t)
        lift = (1.0 - s)[:, None] * np.array([0.0, 0.0, self._lift])
        P = np.broadcast_to(J, (n, *J.shape)).copy() + lift[:, None, :]
        frames = {k: np.broadcast_to(v, (n, 4, 4)).copy() for k, v in F.items()}
        for k in frames:
            frames[k][:, :3, 3] += lift
        R_rel: dict[str, FloatArray] = {}
        for bone, a, b, _, carried in self._LIMBS:
            R = np.asarray(quat_to_matrix(quat_slerp(self._q_stand[bone], self._q_start[bone],
                                                     s)))
            R0 = F[bone][:3, :3]
            rel = R @ R0.T  # world rotation of the segment relative to the start pose
            R_rel[bone] = rel
            origin = P[:, ix[a]]
            for j in (b, *carried):
                P[:, ix[j]] = origin + np.einsum("tij,j->ti", rel, J[ix[j]] - J[ix[a]])
            frames[bone][:, :3, :3] = R
            frames[bone][:, :3, 3] = origin
        for child, seg in self._CHILD_BONES.items():
            if child in F:
                rel = R_rel[seg]
                o_seg = self._J[ix[self._seg_origin(seg)]]
                frames[child][:, :3, :3] = rel @ F[child][:3, :3]
                frames[child][:, :3, 3] = P[:, ix[self._seg_origin(seg)]] + np.einsum(
                    "tij,j->ti", rel, F[child][:3, 3] - o_seg)
        ends = []
        for k, (kind, name) in enumerate(self._cap_ends):
            ref = self._A[k // 2] if k % 2 == 0 else self._B[k // 2]
            if kind == "joint":
                ends.append(P[:, ix[name]])
            else:
                o = J[ix["Knee" + name[len("Ankle"):]]]
                ends.append(P[:, ix["Knee" + name[len("Ankle"):]]]
                            + np.einsum("tij,j->ti", R_rel[kind], ref - o))
        E = np.stack(ends, axis=1)
        return P, frames, E[:, 0::2], E[:, 1::2]

    def _seg_origin(self, seg: str) -> str:
        return next(a for bone, a, *_ in self._LIMBS if bone == seg)

    def joints(self, t: ArrayLike) -> FloatArray:
        """``(T, 25, 3)`` world joint positions (Kinect v2 order).

        Args:
            t: ``(T,)`` true times, s.

        Returns:
            Joint positions, m, world frame (Z up).
        """
        tt = np.atleast_1d(np.asarray(t, dtype=float))
        out = np.asarray(self.walker.joints(np.maximum(tt, self.start_time))).copy()
        pre = tt < self.start_time
        if pre.any():
            out[pre] = self._standing(tt[pre])[0]
        return out

    def bone_frames(self, t: ArrayLike) -> dict[str, FloatArray]:
        """Bone name -> ``(T, 4, 4)`` world poses (the walker's bones and frames).

        Args:
            t: ``(T,)`` true times, s.

        Returns:
            ``T_world_bone`` per bone (m).
        """
        tt = np.atleast_1d(np.asarray(t, dtype=float))
        out = {k: np.asarray(v).copy() for k, v in
               self.walker.bone_frames(np.maximum(tt, self.start_time)).items()}
        pre = tt < self.start_time
        if pre.any():
            fr = self._standing(tt[pre])[1]
            for k in out:
                out[k][pre] = fr[k]
        return out

    def capsule_segments(self, t: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Capsule end points and radii (the walker's capsules).

        Args:
            t: ``(T,)`` true times, s.

        Returns:
            ``(a, b, radii)``: ``(T, C, 3)`` end points (m, world) and ``(C,)`` radii (m).
        """
        tt = np.atleast_1d(np.asarray(t, dtype=float))
        A, B, r = self.walker.capsule_segments(np.maximum(tt, self.start_time))
        A, B = np.asarray(A).copy(), np.asarray(B).copy()
        pre = tt < self.start_time
        if pre.any():
            _, _, As, Bs = self._standing(tt[pre])
            A[pre], B[pre] = As, Bs
        return A, B, np.asarray(r)


def jump_height(t: ArrayLike, jumps: ArrayLike, flight_v: float = 2.2, push: float = 0.25,
                land: float = 0.06) -> FloatArray:
    """Vertical body offset (m) of standing vertical jumps taking off at ``jumps`` (s).

    Push-off at constant acceleration, ballistic flight, a half-sine impact deceleration
    (the landing spike every IMU and the depth torso see), then a smooth (minimum-jerk)
    return to standing height within 0.6 s of the landing.

    Args:
        t: ``(T,)`` times, s.
        jumps: start times of the push-offs, s (at least 1 s apart).
        flight_v: take-off speed, m/s.
        push: push-off duration, s.
        land: duration of the impact deceleration, s.

    Returns:
        ``(T,)`` vertical offset, m.
    """
    tt = np.asarray(t, dtype=float)
    z = np.zeros_like(tt)
    a_push = flight_v / push
    flight = 2 * flight_v / G
    a_land = np.pi * flight_v / (2 * land)
    h_push = 0.5 * a_push * push ** 2
    h0 = h_push - flight_v * land + a_land * land ** 2 / np.pi
    for t0 in np.atleast_1d(np.asarray(jumps, dtype=float)):
        s = tt - t0
        m = (s >= 0) & (s < push)
        z[m] += 0.5 * a_push * s[m] ** 2
        m = (s >= push) & (s < push + flight)
        u = s[m] - push
        z[m] += h_push + flight_v * u - 0.5 * G * u ** 2
        m = (s >= push + flight) & (s < push + flight + 2 * land)
        w = np.minimum(s[m] - push - flight, land)
        z[m] += h_push - flight_v * w + a_land * land / np.pi * (
            w - land / np.pi * np.sin(np.pi * w / land))
        m = (s >= push + flight + 2 * land) & (s < push + flight + 0.6)
        u = (s[m] - push - flight - 2 * land) / (0.6 - 2 * land)
        z[m] += h0 * (1 - u ** 3 * (10 - 15 * u + 6 * u ** 2))
    return z


class Jumping:
    """A subject (walker-like: ``joints``, ``bone_frames``, ``capsule_segments``) that
    performs the seed-002 synchronisation jumps: the whole body is lifted by
    :func:`jump_height`.

    Args:
        subject: e.g. a :class:`StandingStart`.
        jumps: push-off start times, s.
    """

    def __init__(self, subject: Any, jumps: ArrayLike) -> None:
        self.subject = subject
        self.jumps = np.atleast_1d(np.asarray(jumps, dtype=float))
        self.start_time = getattr(subject, "start_time", 0.0)

    def _dz(self, t: ArrayLike) -> FloatArray:
        return jump_height(np.atleast_1d(np.asarray(t, dtype=float)), self.jumps)

    def joints(self, t: ArrayLike) -> FloatArray:
        """``(T, J, 3)`` world joints.

        Args:
            t: ``(T,)`` true times, s.

        Returns:
            Joint positions, m, world frame (Z up).
        """
        J = np.asarray(self.subject.joints(t)).copy()
        J[..., 2] += self._dz(t)[:, None]
        return J

    def bone_frames(self, t: ArrayLike) -> dict[str, FloatArray]:
        """Bone name -> ``(T, 4, 4)`` world poses (the walker's bones and frames).

        Args:
            t: ``(T,)`` true times, s.

        Returns:
            ``T_world_bone`` per bone (m).
        """
        dz = self._dz(t)
        out = {k: np.asarray(v).copy() for k, v in self.subject.bone_frames(t).items()}
        for v in out.values():
            v[:, 2, 3] += dz
        return out

    def capsule_segments(self, t: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Capsule end points and radii (the walker's capsules).

        Args:
            t: ``(T,)`` true times, s.

        Returns:
            ``(a, b, radii)``: ``(T, C, 3)`` end points (m, world) and ``(C,)`` radii (m).
        """
        A, B, r = self.subject.capsule_segments(t)
        dz = self._dz(t)[:, None]
        A, B = np.asarray(A).copy(), np.asarray(B).copy()
        A[..., 2] += dz
        B[..., 2] += dz
        return A, B, np.asarray(r)
