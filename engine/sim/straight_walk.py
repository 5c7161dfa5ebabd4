"""Synthetic straight walks with exact ground truth (minimum-jerk feet; for tests and benches).

Kinematics: feet are placed alternately (left first) at ``k·step_length`` along the
walking direction, ``±step_width/2`` to the side; each foot swings with a minimum-jerk
horizontal profile, a sin² heel lift (zero vertical velocity at landing) and a sin toe
lift (fastest rise at lift-off), leaving the floor ``double_support_s`` after the other
foot lands. The pelvis moves at the mean speed. Exact ground truth: step length, width
and time, strike and off times.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from engine.errors import InputError
from engine.geometry import invert_transform, look_at, transform_points
from engine.io.markers import MarkerTrajectories
from engine.skeleton import KINECT_V2, SkeletonSeries, TrackingState

FloatArray = NDArray[np.float64]


@dataclass
class SynthWalk:
    """A straight walk with its ground truth."""

    times: FloatArray
    joints: dict[str, FloatArray]  # name -> (T, 3), world, Z up
    strikes: list[tuple[str, float, FloatArray]]  # side, time, heel position at landing
    offs: list[tuple[str, float]]
    step_length: float
    step_width: float
    step_time: float
    double_support_s: float


def synth_walk(step_length: float = 0.7, step_width: float = 0.12, step_time: float = 0.55,
               n_steps: int = 10, rate: float = 100.0, double_support_s: float = 0.1,
               origin: tuple[float, float, float] = (0.0, 0.0, 0.0), heading_deg: float = 0.0,
               side_bias: float = 0.0) -> SynthWalk:
    """A walk of ``n_steps`` strikes (left first) starting at full speed.

    Args:
        step_length: Step length, m.
        step_width: Step width, m.
        step_time: Step time, s.
        n_steps: Number of foot strikes.
        rate: Sampling rate, Hz.
        double_support_s: Double-support time, s.
        origin: World point on the walking line (midway between the feet) level with the
            first (left) strike's ankle, m; the walk is rotated about it by ``heading_deg``.
        heading_deg: Walking direction, degrees from world +X, counter-clockwise.
        side_bias: Shifts the right foot's placements laterally (m; an asymmetric gait).

    Returns:
        The walk with its ground truth (joints in m, world Z up, on ``times``; strikes
        and offs).
    """
    Ls, W, Ts, ds = step_length, step_width, step_time, double_support_s
    v = Ls / Ts
    T_end = (n_steps - 1) * Ts + 0.3
    t = np.arange(0.0, T_end, 1.0 / rate)
    ks = range(-3, n_steps + 3)
    place = {k: ("L" if k % 2 == 0 else "R", k * Ls,
                 (W / 2 if k % 2 == 0 else -W / 2 - side_bias), k * Ts) for k in ks}
    local: dict[str, FloatArray] = {}
    for side in ("L", "R"):
        x = np.zeros_like(t)
        y = np.zeros_like(t)
        lift = np.zeros_like(t)
        toe_lift = np.zeros_like(t)
        for k in ks:
            s_k, xk, yk, tk = place[k]
            if s_k != side or k - 2 not in place:
                continue
            _, xp, yp, tp = place[k - 2]
            # Lift-off ds after the other foot lands; the same expression as the stance
            # end below so that no sample falls between stance and swing.
            t_lift = tp + Ts + ds
            sw = (t >= t_lift) & (t < tk)
            st = (t >= tk) & (t < tk + Ts + ds)
            s = (t[sw] - t_lift) / (tk - t_lift)
            h = 10 * s**3 - 15 * s**4 + 6 * s**5
            x[sw] = xp + (xk - xp) * h
            y[sw] = yp + (yk - yp) * h
            lift[sw] = np.sin(np.pi * s) ** 2
            # The toe leaves the floor at its fastest rise (the foot-velocity algorithm's
            # toe-off) and touches down after the heel.
            toe_lift[sw] = np.sin(np.pi * s)
            x[st] = xk
            y[st] = yk
        ankle = np.stack([x, y, 0.08 + 0.10 * lift], axis=1)
        local[f"heel{side}"] = ankle + np.array([-0.05, 0.0, -0.05])
        local[f"toe{side}"] = np.stack([x + 0.15, y, 0.03 + 0.10 * toe_lift], axis=1)
        local[f"ankle{side}"] = ankle
    px = v * t - Ls / 2
    sway = 0.02 * np.sin(np.pi * t / Ts)
    local["pelvis"] = np.stack([px, sway, np.full_like(t, 0.95)], axis=1)

    a = np.radians(heading_deg)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])
    o = np.asarray(origin, dtype=float)
    joints = {n: p @ R.T + o for n, p in local.items()}
    strikes = []
    offs = []
    for k in range(n_steps):
        s_k, xk, yk, tk = place[k]
        strikes.append((s_k, tk, R @ np.array([xk - 0.05, yk, 0.03]) + o))
        if tk + ds < T_end:
            offs.append(("R" if s_k == "L" else "L", tk + ds))
    return SynthWalk(t, joints, strikes, offs, Ls, W, Ts, ds)


def walk_markers(w: SynthWalk, labels: dict[str, str] | None = None,
                 up: str = "z") -> MarkerTrajectories:
    """The walk as a marker set (Plug-in Gait names unless ``labels`` maps them).

    An ankle named as a lateral-malleolus marker (``LANK``, ``L.Ankle.Lat``:
    :func:`engine.io.markers.is_lateral_ankle`) sits where Plug-in Gait puts it, on the
    lateral malleolus of a subject with the population ankle width:
    :data:`engine.mocap.DEFAULT_ANKLE_WIDTH_M` / 2 + :data:`engine.mocap.DEFAULT_MARKER_DIAMETER_M`
    / 2 outside the ankle joint, perpendicular to the foot's heel→toe axis. The walk's
    ground truth (widths between the joints) is then what the crossing method's joint
    centre recovers. Other names (``AnkleLeft``, ``L_Ankle``) are the joint itself.

    Args:
        w: The walk.
        labels: Walk point (``ankleL``, ``heelR``, ``toeL`` ...) -> marker label; pelvis
            markers LASI, RASI, LPSI, RPSI are always added.
        up: ``"z"`` (world, Z up) or ``"y"`` (Y up, as OpenSim and many labs write:
            X = the world's Y, Y = its Z, Z = its X, still right-handed).

    Returns:
        Marker trajectories in metres on the walk's time axis.

    Raises:
        InputError: ``up`` is neither ``"z"`` nor ``"y"``.
    """
    if up not in ("z", "y"):  # "-y" or "x" gave Z up without a word
        raise InputError(f"walk_markers: up must be 'z' or 'y', got {up!r}; for another "
                         "axis rotate the positions (engine.io.up_rotation gives the "
                         "rotation taking an axis to +Z)")
    names = labels or {"ankleL": "LANK", "ankleR": "RANK", "heelL": "LHEE", "heelR": "RHEE",
                       "toeL": "LTOE", "toeR": "RTOE"}
    from engine.io.markers import is_lateral_ankle
    from engine.mocap import DEFAULT_ANKLE_WIDTH_M, DEFAULT_MARKER_DIAMETER_M

    P = []
    for k, lab in names.items():
        x = w.joints[k]
        side = k[-1]
        if k.startswith("ankle") and is_lateral_ankle(lab, side):
            f = w.joints[f"toe{side}"] - w.joints[f"heel{side}"]
            left = np.stack([-f[:, 1], f[:, 0], np.zeros(len(f))], axis=1)
            left /= np.linalg.norm(left, axis=1, keepdims=True)
            half = 0.5 * (DEFAULT_ANKLE_WIDTH_M + DEFAULT_MARKER_DIAMETER_M)
            x = x + (half if side == "L" else -half) * left
        P.append(x)
    labs = list(names.values())
    pel = w.joints["pelvis"]
    for lab, off in (("LASI", (0.05, 0.12, 0.0)), ("RASI", (0.05, -0.12, 0.0)),
                     ("LPSI", (-0.12, 0.05, 0.02)), ("RPSI", (-0.12, -0.05, 0.02))):
        P.append(pel + np.array(off))
        labs.append(lab)
    X = np.stack(P, axis=1)
    if up == "y":
        X = np.stack([X[..., 1], X[..., 2], X[..., 0]], axis=-1)
    rate = round(1.0 / float(np.median(np.diff(w.times))), 6)
    # metres always: a file in other units is made by the writer (``write_trc(units=…)``)
    return MarkerTrajectories(w.times, X, labs, rate, "m")


def walk_skeleton(w: SynthWalk) -> FloatArray:
    """``(T, 25, 3)`` Kinect v2 joints (world) of the walk: a plausible stick figure.

    Args:
        w: The walk.

    Returns:
        Joint positions, m, world frame (Z up), KINECT_V2 order, on ``w.times``.
    """
    T = len(w.times)
    J = KINECT_V2.joints
    P = np.zeros((T, len(J), 3))
    pel = w.joints["pelvis"]
    aL, aR = w.joints["ankleL"], w.joints["ankleR"]
    fwd = np.gradient(pel, w.times, axis=0)
    fwd[:, 2] = 0
    fwd /= np.maximum(np.linalg.norm(fwd, axis=1, keepdims=True), 1e-9)
    lat = np.cross([0, 0, 1.0], fwd)
    up = np.array([0, 0, 1.0])

    def put(name: str, x: FloatArray) -> None:
        P[:, J.index(name)] = x

    put("SpineBase", pel)
    put("SpineMid", pel + 0.25 * up)
    put("SpineShoulder", pel + 0.5 * up)
    put("Neck", pel + 0.58 * up)
    put("Head", pel + 0.72 * up)
    for s, S, sg, a in (("L", "Left", 1.0, aL), ("R", "Right", -1.0, aR)):
        hip = pel + sg * 0.1 * lat - 0.05 * up
        put(f"Hip{S}", hip)
        put(f"Knee{S}", 0.5 * (hip + a) + 0.04 * fwd)
        put(f"Ankle{S}", a)
        put(f"Foot{S}", w.joints[f"toe{s}"])
        sh = pel + 0.48 * up + sg * 0.18 * lat
        put(f"Shoulder{S}", sh)
        put(f"Elbow{S}", sh - 0.28 * up)
        put(f"Wrist{S}", sh - 0.52 * up + 0.02 * fwd)
        put(f"Hand{S}", sh - 0.58 * up + 0.02 * fwd)
        put(f"HandTip{S}", sh - 0.66 * up + 0.02 * fwd)
        put(f"Thumb{S}", sh - 0.58 * up + 0.05 * fwd)
    return P


def avenue_poses() -> list[tuple[str, FloatArray]]:
    """Six sensors as in the seed paper's avenue.

    Pairs at x = 2.4, 4.9, 7.4 m, y = ±1 m, 1 m high, looking back along −X, toed in 35°
    toward the walkway.

    Returns:
        ``(sensor id, T_world_sensor)`` for S1 ... S6.
    """
    out = []
    for k, x in enumerate((2.4, 4.9, 7.4)):
        for j, sg in enumerate((1.0, -1.0)):
            yaw = np.radians(180.0 + sg * 35.0)
            eye = np.array([x, sg * 1.0, 1.0])
            d = np.array([np.cos(yaw), np.sin(yaw), -0.14])
            out.append((f"S{2 * k + j + 1}", look_at(eye, eye + d)))
    return out


def observe(truth: FloatArray, times_true: FloatArray, T_world_sensor: FloatArray,
            rng: np.random.Generator, noise_m: float = 0.01, occluded_bias_m: float = 0.0,
            near_bias_m: float = 0.0,
            clock_offset_s: float = 0.0, clock_drift_ppm: float = 0.0,
            drop: tuple[float, float] | None = None, max_range_m: float = 4.5,
            inferred_frac: float = 0.0) -> SkeletonSeries:
    """One sensor's view of a world skeleton: sensor frame, local clock.

    Joints are pulled toward the sensor's side (the seed paper's Fig. 5B: each sensor's
    joints lie closer to the surface it sees): by ``occluded_bias_m`` on the body half
    facing away from the sensor, by ``near_bias_m`` on the half facing it. ``drop``
    blanks a true-time interval; joints beyond ``max_range_m`` are NOT_TRACKED; a random
    fraction is INFERRED.

    Args:
        truth: ``(T, 25, 3)`` world skeleton (Kinect v2 order), m.
        times_true: ``(T,)`` true times, s.
        T_world_sensor: The sensor's 4×4 pose.
        rng: Random generator.
        noise_m: Joint noise, m (1σ).
        occluded_bias_m: Pull of the far body half towards the sensor, m.
        near_bias_m: Pull of the near half, m.
        clock_offset_s: The sensor clock's offset, s.
        clock_drift_ppm: Its drift, ppm.
        drop: A true-time interval ``(t0, t1)`` blanked.
        max_range_m: Farthest tracked joint, m.
        inferred_frac: Share of joints reported INFERRED.

    Returns:
        The series in the sensor frame on the sensor's clock.
    """
    c = T_world_sensor[:3, 3]
    T, J = truth.shape[:2]
    pel = truth[:, KINECT_V2.index("SpineBase")]
    lat = truth[:, KINECT_V2.index("HipLeft")] - truth[:, KINECT_V2.index("HipRight")]
    lat[:, 2] = 0
    lat /= np.linalg.norm(lat, axis=1, keepdims=True)
    sides = np.array([1.0 if "Left" in n else -1.0 if "Right" in n else 0.0
                      for n in KINECT_V2.joints])
    to_s = c - truth
    to_s_h = to_s.copy()
    to_s_h[..., 2] = 0
    to_s_h /= np.maximum(np.linalg.norm(to_s_h, axis=-1, keepdims=True), 1e-9)
    cos = np.einsum("tjk,tk->tj", to_s_h, lat) * sides[None]
    occl = cos < 0
    # The sensor's side of the body, as a unit lateral vector.
    sensor_side = np.sign(np.einsum("tk,tk->t", c - pel, lat))[:, None] * lat
    pull = np.where(occl, occluded_bias_m, np.where(sides[None] != 0, near_bias_m, 0.0))
    obs = truth + pull[..., None] * sensor_side[:, None, :]
    obs = obs + rng.normal(0.0, noise_m, obs.shape)
    states = np.full((T, J), TrackingState.TRACKED, dtype=np.uint8)
    dist = np.linalg.norm(c - pel, axis=1)
    states[dist > max_range_m] = TrackingState.NOT_TRACKED
    if inferred_frac > 0:
        states[(rng.random((T, J)) < inferred_frac) & (states == TrackingState.TRACKED)] = \
            TrackingState.INFERRED
    if drop is not None:
        states[(times_true >= drop[0]) & (times_true <= drop[1])] = TrackingState.NOT_TRACKED
    P = transform_points(invert_transform(T_world_sensor), obs)
    P[states == TrackingState.NOT_TRACKED] = np.nan
    t_local = clock_offset_s + (1 + clock_drift_ppm * 1e-6) * times_true
    return SkeletonSeries(t_local, P, states, KINECT_V2, {})


def sample_truth(w: SynthWalk, truth: FloatArray, times: FloatArray) -> FloatArray:
    """World skeleton ``truth`` (on ``w.times``) linearly sampled at ``times``.

    Args:
        w: The walk (its ``times``).
        truth: ``(T, J, 3)`` world skeleton on ``w.times``, m.
        times: ``(N,)`` true times, s.

    Returns:
        ``(N, J, 3)`` world skeleton, m.
    """
    out = np.empty((len(times), *truth.shape[1:]))
    for j in range(truth.shape[1]):
        for c in range(3):
            out[:, j, c] = np.interp(times, w.times, truth[:, j, c])
    return out


def six_sensor_streams(w: SynthWalk, rng: np.random.Generator, noise_m: float = 0.01,
                       occluded_bias_m: float = 0.04, near_bias_m: float = 0.0,
                       clocks: bool = True,
                       inferred_frac: float = 0.05,
                       drop: tuple[float, float] | None = None) -> list:  # list[SensorStream]
    """Six avenue sensors observing the walk at ~30 Hz (jittered) on their own clocks.

    Args:
        w: The walk.
        rng: Random generator (noise, clocks, frame times).
        noise_m: Joint position noise, m (1σ).
        occluded_bias_m: Pull of the body half facing away from each sensor towards it, m.
        near_bias_m: The same for the half facing it, m.
        clocks: Random clock offsets (±0.5 s) and drifts (±100 ppm); False: ideal clocks.
        inferred_frac: Share of joints reported INFERRED.
        drop: A true-time interval ``(t0, t1)`` blanked in every stream.

    Returns:
        One :class:`~engine.integration.SensorStream` per sensor (S1 ... S6: sensor frame,
        local clock, ``T_world_sensor`` and the clock model).
    """
    from engine.integration import SensorStream

    truth = walk_skeleton(w)
    streams = []
    for sid, T in avenue_poses():
        off = float(rng.uniform(-0.5, 0.5)) if clocks else 0.0
        drift = float(rng.uniform(-100, 100)) if clocks else 0.0
        n = int((w.times[-1] - w.times[0]) * 30) + 5
        tt = w.times[0] + rng.uniform(0, 0.03) + np.cumsum(
            np.full(n, 1 / 30) * (1 + 0.05 * rng.standard_normal(n)))
        tt = tt[tt < w.times[-1]]
        s = observe(sample_truth(w, truth, tt), tt, T, rng, noise_m=noise_m,
                    occluded_bias_m=occluded_bias_m, near_bias_m=near_bias_m,
                    clock_offset_s=off,
                    clock_drift_ppm=drift, inferred_frac=inferred_frac, drop=drop)
        streams.append(SensorStream(s, T, off, drift, sid))
    return streams
