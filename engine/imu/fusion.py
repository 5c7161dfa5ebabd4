"""Fused depth/IMU skeleton (seed paper 002 §2.3-2.4) and joint angles (§3.2).

Pipeline:

1. **Plank initialisation** (:func:`plank_calibration`): while all IMUs lie on a rigid
   plank they share one orientation, known in the depth (Kinect) world frame
   (``q_world_plank``; identity when the plank is aligned with the Kinect axes as in the
   paper's Fig. 1a). Each sensor's filter output at that moment then gives the fixed
   rotation from its own earth frame to the world frame, ``q_W_E = q_world_plank ⊗ q(t_p)*``
   — this removes per-sensor heading differences (arbitrary in 6D) and the IMU-to-Kinect
   frame rotation at once.
2. **Bone mapping**: nine sensors on forearms, upper arms, thighs, shanks and the chest
   (:data:`PAPER_SENSORS`, Fig. 1b). The torso joint ``T`` (Kinect v2 ``SpineMid``) follows
   the depth skeleton.
3. **Reference skeleton** (:func:`select_reference_frame`): the depth frame where the
   joints move least over a short window, i.e. the most stable still frame — chosen
   automatically as the paper suggests.
4. **Hierarchical rotation**: each bone is rotated by its sensor's rotation since the
   reference frame, torso first (shoulders and hips follow the chest sensor), then upper
   arms and thighs, then forearms and shanks. The paper composes the per-sample
   increments Δq = q_t* ⊗ q_{t+1} (eq. 5-6); composing them from the reference time gives
   ``q_ref* ⊗ q_t`` in the sensor frame, which we apply in closed form (same result, no
   accumulation of rounding over thousands of samples). Because the bone vector is
   expressed in the sensor frame at the reference time, a sensor need not be aligned with
   its bone (the mounting convention of Fig. 1b only matters for reading axes).
   The constant joint-angle offset the paper observed comes from that sensor-frame bone
   vector: taken from the reference skeleton (``bone_fit="reference"``, the paper's
   method) or even fitted to every depth frame (``"all"``), the depth tracker's
   systematic bone-direction errors (a few degrees, in the sagittal plane when the
   subject faces the sensor) become a fixed flexion error. By default
   (``bone_fit="standing"``) we use what the protocol knows instead: in the standing
   calibration pose (Fig. 1b: bones pointing to the ground) knees and elbows are extended,
   so thigh and shank (upper arm and forearm) share one direction; taking that common
   direction for both segments makes the flexion exact to second order in the depth
   error. The reference frame is chosen where every IMU is still.
5. **Joint angles**: :func:`joint_rotation` is q_prox* ⊗ q_dist (eq. 7);
   :func:`flexion_angles` gives knee and elbow flexion (degrees, 0 = straight) from any
   skeleton, so depth-only, fused and reference are measured the same way; :func:`rmse`
   and :func:`ncc` are Table 1's measures.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.errors import InputError, InsufficientDataError
from engine.geometry import quat_conj, quat_mul, quat_normalize, quat_rotate, quat_slerp
from engine.imu.metrics import ncc, rmse
from engine.skeleton import JointSet, SkeletonSeries, TrackingState
from engine.wording import named

FloatArray = NDArray[np.float64]

__all__ = [
    "PAPER_SENSORS",
    "STRAIGHT_LIMBS",
    "FusedSkeleton",
    "PlankCalibration",
    "delta_quaternions",
    "flexion_angles",
    "fuse_skeleton",
    "imu_still_frames",
    "interp_quat",
    "joint_rotation",
    "ncc",
    "plank_calibration",
    "rmse",
    "select_reference_frame",
]

#: Sensor name -> (proximal joint role, distal joint role) of the bone it drives, with the
#: rigidly attached joints moved along (roles from ``engine.skeleton``). Chest = torso T.
PAPER_SENSORS: dict[str, tuple[str, str]] = {
    "chest": ("spine_mid", "spine_top"),
    "upperarm_l": ("shoulder_left", "elbow_left"),
    "forearm_l": ("elbow_left", "wrist_left"),
    "upperarm_r": ("shoulder_right", "elbow_right"),
    "forearm_r": ("elbow_right", "wrist_right"),
    "thigh_l": ("hip_left", "knee_left"),
    "shank_l": ("knee_left", "ankle_left"),
    "thigh_r": ("hip_right", "knee_right"),
    "shank_r": ("knee_right", "ankle_right"),
}

# Joints carried rigidly by each sensor's segment (roles), beyond the bone's distal joint.
_CARRIED: dict[str, tuple[str, ...]] = {
    "chest": ("pelvis", "spine_top", "neck", "head", "shoulder_left", "shoulder_right",
              "hip_left", "hip_right"),
    "upperarm_l": ("elbow_left",), "upperarm_r": ("elbow_right",),
    "forearm_l": ("wrist_left", "hand_left"), "forearm_r": ("wrist_right", "hand_right"),
    "thigh_l": ("knee_left",), "thigh_r": ("knee_right",),
    "shank_l": ("ankle_left", "foot_left"), "shank_r": ("ankle_right", "foot_right"),
}
#: Limb sensors -> (root role, end role) of the limb that is straight in the standing
#: calibration pose (knees and elbows extended, Fig. 1b): both of its segments then point
#: along root -> end.
STRAIGHT_LIMBS: dict[str, tuple[str, str]] = {
    "thigh_l": ("hip_left", "ankle_left"), "shank_l": ("hip_left", "ankle_left"),
    "thigh_r": ("hip_right", "ankle_right"), "shank_r": ("hip_right", "ankle_right"),
    "upperarm_l": ("shoulder_left", "wrist_left"), "forearm_l": ("shoulder_left", "wrist_left"),
    "upperarm_r": ("shoulder_right", "wrist_right"),
    "forearm_r": ("shoulder_right", "wrist_right"),
}
# Order of the hierarchy: torso, then proximal limb segments, then distal ones.
_ORDER = ("chest", "upperarm_l", "upperarm_r", "thigh_l", "thigh_r", "forearm_l",
          "forearm_r", "shank_l", "shank_r")


@dataclass(frozen=True)
class PlankCalibration:
    """Per-sensor rotation from the sensor's earth frame to the depth world frame.

    Attributes:
        q_world_earth: sensor name -> ``(4,)`` quaternion ``q_W_E``.
        time: plank time used (s, common clock).
        spread_deg: sensor name -> angle between this sensor's tilt and the median tilt at
            the plank time (large values mean a sensor was not on the plank).
    """

    q_world_earth: dict[str, FloatArray]
    time: float
    spread_deg: dict[str, float] = field(default_factory=dict)

    def to_world(self, name: str, q: ArrayLike) -> FloatArray:
        """Sensor-to-world quaternions of sensor ``name`` from its filter output ``q``.

        Args:
            name: A sensor that was on the plank.
            q: ``(..., 4)`` sensor-to-earth quaternions (w first) from its filter.

        Returns:
            ``(..., 4)`` sensor-to-world quaternions (``q_W_E ⊗ q``; world: the depth
            skeleton's, Z up).

        Raises:
            InputError: the sensor was not on the plank.
        """
        if name not in self.q_world_earth:
            raise InputError(f"sensor {name!r} was not on the plank; have "
                             f"{sorted(self.q_world_earth)}")
        return quat_mul(self.q_world_earth[name], np.asarray(q, dtype=float))


def interp_quat(times: FloatArray, q: FloatArray, t: ArrayLike) -> FloatArray:
    """Slerp a ``(T, 4)`` quaternion series sampled at ``times`` at the times ``t``.

    Times outside the series' span are clamped to its ends.

    Args:
        times: ``(T,)`` increasing sample times, s.
        q: ``(T, 4)`` unit quaternions, w first.
        t: ``(N,)`` query times, s.

    Returns:
        ``(N, 4)`` unit quaternions.
    """
    tq = np.clip(np.asarray(t, dtype=float), times[0], times[-1])
    i = np.clip(np.searchsorted(times, tq, side="right") - 1, 0, len(times) - 2)
    u = (tq - times[i]) / (times[i + 1] - times[i])
    return quat_slerp(q[i], q[i + 1], u)


def plank_calibration(
    times: ArrayLike,
    orientations: Mapping[str, ArrayLike],
    plank_time: float,
    q_world_plank: ArrayLike = (1.0, 0.0, 0.0, 0.0),
    max_spread_deg: float = 10.0,
) -> PlankCalibration:
    """Fixed earth-to-world rotation of every sensor from a plank pose (paper §2.3).

    Args:
        times: ``(T,)`` common time stamps of the orientation series (s).
        orientations: sensor name -> ``(T, 4)`` filter output (sensor-to-earth).
        plank_time: a time at which all sensors lay aligned on the plank.
        q_world_plank: orientation of the plank (= every sensor) in the world frame.
        max_spread_deg: tilt disagreement above which a sensor is rejected.

    Returns:
        Per sensor ``q_world_earth`` (its earth frame → the world frame), the plank time
        and each sensor's tilt spread, degrees.

    Raises:
        InputError: plank time outside the recording, or a sensor whose tilt disagrees
            with the others (it was not on the plank).
    """
    t = np.asarray(times, dtype=float)
    if not t[0] <= plank_time <= t[-1]:
        raise InputError(f"plank time {plank_time:.3f} s is outside the IMU recording "
                         f"[{t[0]:.3f}, {t[-1]:.3f}] s")
    qp = quat_normalize(np.asarray(q_world_plank, dtype=float))
    q_at = {n: quat_normalize(interp_quat(t, np.asarray(q, dtype=float), plank_time))
            for n, q in orientations.items()}
    # All sensors share their attitude on the plank: compare each one's "up" seen in the
    # sensor frame (independent of each filter's arbitrary heading).
    ups = {n: quat_rotate(quat_conj(q), np.array([0.0, 0.0, 1.0])) for n, q in q_at.items()}
    med = np.median(np.stack(list(ups.values())), axis=0)
    med /= np.linalg.norm(med)
    spread = {n: float(np.degrees(np.arccos(np.clip(u @ med, -1.0, 1.0))))
              for n, u in ups.items()}
    bad = [n for n, s in spread.items() if s > max_spread_deg]
    if bad:
        raise InputError(f"{named('sensor', bad, 'was', 'were')} not aligned with the others "
                         f"at the plank time {plank_time:.2f} s (tilt differs by > "
                         f"{max_spread_deg}°)")
    return PlankCalibration({n: quat_mul(qp, quat_conj(q)) for n, q in q_at.items()},
                            float(plank_time), spread)


def delta_quaternions(q: ArrayLike) -> FloatArray:
    """Per-sample rotation increments Δq_{t+1} = q_t* ⊗ q_{t+1} (eq. 5).

    Args:
        q: ``(T, 4)`` orientations, w first (time first axis).

    Returns:
        ``(T-1, 4)`` increments, each in the frame of the earlier sample.
    """
    qq = np.asarray(q, dtype=float)
    return quat_mul(quat_conj(qq[:-1]), qq[1:])


def joint_rotation(q_prox: ArrayLike, q_dist: ArrayLike) -> FloatArray:
    """Joint rotation ``q_prox* ⊗ q_dist`` (eq. 7): distal segment relative to proximal.

    Args:
        q_prox: ``(..., 4)`` proximal segment orientations (w first, same earth frame).
        q_dist: ``(..., 4)`` distal segment orientations.

    Returns:
        ``(..., 4)`` rotation of the distal segment in the proximal segment's frame.
    """
    return quat_mul(quat_conj(np.asarray(q_prox, dtype=float)), np.asarray(q_dist, dtype=float))


def select_reference_frame(
    skeleton: SkeletonSeries,
    roles: tuple[str, ...] | None = None,
    window: float = 0.5,
    t_min: float | None = None,
    t_max: float | None = None,
    candidates: NDArray[np.bool_] | None = None,
) -> int:
    """Index of the most stable still depth frame (paper §2.4, automated).

    A frame's instability is the mean, over the needed joints, of the positional standard
    deviation in a centred window of ``window`` seconds; frames whose window has any
    needed joint not TRACKED are excluded.

    Args:
        skeleton: the depth skeleton.
        roles: joint roles that must be stable (default: the end points of the sensor
            bones and the hips).
        window: window length, s.
        t_min, t_max: restrict the search to this time range (e.g. the IMU recording).
        candidates: ``(T,)`` frames allowed as centre (e.g. where the IMUs are still).

    Returns:
        The frame index into ``skeleton``.

    Raises:
        InsufficientDataError: no window with all needed joints tracked.
    """
    js = skeleton.joint_set
    # the bone end points must be tracked; hands, feet and head are often only inferred
    rl = roles or tuple(sorted({r for s in PAPER_SENSORS for r in PAPER_SENSORS[s]}
                               | {"pelvis", "hip_left", "hip_right"}))
    idx = [js.role_index(r) for r in rl]
    P = skeleton.tracked_positions()[:, idx, :]
    t = skeleton.times
    T = len(t)
    if T < 3:
        raise InsufficientDataError("the depth skeleton needs at least three frames")
    dt = float(np.median(np.diff(t)))
    h = max(1, round(0.5 * window / dt))
    best, best_score = -1, np.inf
    lo = -np.inf if t_min is None else t_min
    hi = np.inf if t_max is None else t_max
    ok_frame = np.all(np.isfinite(P), axis=(1, 2))
    # cumulative sums make every window's variance O(1)
    X = np.where(np.isfinite(P), P, 0.0).reshape(T, -1)
    c1 = np.vstack([np.zeros(X.shape[1]), np.cumsum(X, axis=0)])
    c2 = np.vstack([np.zeros(X.shape[1]), np.cumsum(X * X, axis=0)])
    cbad = np.r_[0, np.cumsum(~ok_frame)]
    for k in range(h, T - h):
        if not lo <= t[k] <= hi or (candidates is not None and not candidates[k]):
            continue
        a, b = k - h, k + h + 1
        if cbad[b] - cbad[a] > 0:
            continue
        n = b - a
        var = (c2[b] - c2[a]) / n - ((c1[b] - c1[a]) / n) ** 2
        score = float(np.mean(np.sqrt(np.maximum(var.reshape(-1, 3).sum(axis=1), 0.0))))
        if score < best_score:
            best, best_score = k, score
    if best < 0:
        raise InsufficientDataError(
            f"no {window:.1f} s window with all fusion joints tracked; record a moment of "
            "standing still facing the sensor")
    return best


@dataclass
class FusedSkeleton:
    """Result of :func:`fuse_skeleton`.

    Attributes:
        skeleton: fused joints on the IMU time grid (joints not driven are NaN).
        reference_index: index of the depth frame used as reference skeleton.
        sensor_world: sensor name -> ``(T, 4)`` sensor-to-world orientation.
        warnings: calibration problems worth showing (e.g. a limb not straight in the
            standing pose).
    """

    skeleton: SkeletonSeries
    reference_index: int
    sensor_world: dict[str, FloatArray]
    warnings: list[str] = field(default_factory=list)


def imu_still_frames(
    times: FloatArray,
    q_world: Mapping[str, FloatArray],
    frame_times: FloatArray,
    window: float,
    max_rate: float = 0.15,
) -> NDArray[np.bool_]:
    """Frames around which every sensor is still for ``window`` seconds.

    Args:
        times: ``(T,)`` IMU time grid, s.
        q_world: sensor -> ``(T, 4)`` orientations on that grid.
        frame_times: ``(F,)`` depth frame times, s.
        window: window length centred on each frame, s.
        max_rate: angular speed (rad/s) above which a sensor counts as moving.

    Returns:
        ``(F,)`` bool.
    """
    moving = np.zeros(len(times), dtype=bool)
    dt = np.diff(times)
    for q in q_world.values():
        d = quat_mul(quat_conj(q[:-1]), q[1:])
        rate = 2.0 * np.arccos(np.clip(np.abs(d[:, 0]), 0.0, 1.0)) / np.maximum(dt, 1e-9)
        moving[1:] |= rate > max_rate
    cm = np.r_[0, np.cumsum(moving)]
    a = np.searchsorted(times, frame_times - 0.5 * window, side="left")
    b = np.searchsorted(times, frame_times + 0.5 * window, side="right")
    inside = (frame_times - 0.5 * window >= times[0]) & (frame_times + 0.5 * window
                                                         <= times[-1])
    return np.asarray(inside & (cm[b] - cm[a] == 0))


def _fit_segment_vector(v_world: FloatArray, q_ws: FloatArray) -> FloatArray | None:
    """Robust mean of a joint offset expressed in the sensor frame over many frames.

    ``v_world`` ``(T, 3)`` offsets (NaN where untracked), ``q_ws`` ``(T, 4)`` sensor-to-world
    orientations at the same times. Outliers (e.g. left/right label swaps of the depth
    tracker) are rejected beyond three robust standard deviations from the median.
    """
    ok = np.isfinite(v_world).all(axis=1) & np.isfinite(q_ws).all(axis=1)
    if ok.sum() < 3:
        return None
    v_s = quat_rotate(quat_conj(q_ws[ok]), v_world[ok])
    med = np.median(v_s, axis=0)
    d = np.linalg.norm(v_s - med, axis=1)
    mad = 1.4826 * float(np.median(d)) + 1e-9
    keep = d <= 3.0 * mad
    return np.asarray(v_s[keep].mean(axis=0) if keep.sum() >= 3 else med)


def _standing_bone_vectors(
    tracked: FloatArray,
    win: NDArray[np.bool_],
    ref: FloatArray,
    smap: Mapping[str, tuple[str, str]],
    js: JointSet,
    q_world: Mapping[str, FloatArray],
    interp_quat_fn: Callable[[FloatArray], FloatArray],
    max_flexion_deg: float,
    warnings: list[str],
    flexion_estimate: Mapping[tuple[str, str], float],
) -> dict[str, FloatArray]:
    """Sensor-frame bone vectors of the limb segments from the straight standing pose.

    Args:
        tracked: ``(T_depth, J, 3)`` tracked depth joints (NaN elsewhere).
        win: ``(T_depth,)`` frames of the still standing window.
        ref: ``(J, 3)`` averaged reference skeleton.
        smap: sensor -> (proximal role, distal role).
        js: joint set.
        q_world: sensor -> sensor-to-world orientation on the IMU grid.
        interp_quat_fn: resamples an IMU-grid quaternion series at the window's frames.
        max_flexion_deg: limbs bent more than this in the standing pose are not treated
            as straight.
        flexion_estimate: (root role, end role) -> flexion (degrees) of that limb in the
            standing pose, when known better than from ``ref`` (a single depth window
            of a distant subject is too noisy: elbows read 30° off and more).
        warnings: appended with the limbs that were not straight.

    Returns:
        sensor -> ``(3,)`` vector from the proximal to the distal joint, sensor frame.
    """
    out: dict[str, FloatArray] = {}
    bent: set[tuple[str, str]] = set()
    if win.sum() == 0:
        return out
    for name, (prox, dist) in smap.items():
        if name not in STRAIGHT_LIMBS or name not in q_world:
            continue
        root_r, end_r = STRAIGHT_LIMBS[name]
        root, end = js.role_index(root_r), js.role_index(end_r)
        ip, idist = js.role_index(prox), js.role_index(dist)
        flex = flexion_estimate.get((root_r, end_r))
        if flex is None:
            mid = idist if idist != end else ip
            u, v = ref[mid] - ref[root], ref[end] - ref[mid]
            if not (np.isfinite(u).all() and np.isfinite(v).all()):
                continue
            flex = float(np.degrees(np.arccos(np.clip(
                u @ v / (np.linalg.norm(u) * np.linalg.norm(v)), -1, 1))))
        if flex > max_flexion_deg:
            if (root_r, end_r) not in bent:
                bent.add((root_r, end_r))
                warnings.append(
                    f"{root_r.split('_')[0]}-{end_r} limb bent by {flex:.0f}° in the "
                    "reference (standing) pose; its segments are fitted to the whole "
                    "recording instead — stand straight, knees and elbows extended, for "
                    "the calibration")
            continue
        chain = tracked[win][:, end] - tracked[win][:, root]
        ok = np.isfinite(chain).all(axis=1)
        if ok.sum() == 0:
            continue
        d = chain[ok].mean(axis=0)
        d /= np.linalg.norm(d)
        q_w = interp_quat_fn(q_world[name])[ok]
        b = quat_rotate(quat_conj(q_w), np.broadcast_to(d, (len(q_w), 3))).mean(axis=0)
        seg = np.linalg.norm(tracked[:, idist] - tracked[:, ip], axis=1)
        seg = seg[np.isfinite(seg)]
        length = float(np.median(seg)) if len(seg) else float(np.linalg.norm(
            ref[idist] - ref[ip]))
        out[name] = length * b / np.linalg.norm(b)
    return out


def _standing_flexion(
    tracked: FloatArray,
    depth_times: FloatArray,
    t: FloatArray,
    q_world: Mapping[str, FloatArray],
    q_ref: Mapping[str, FloatArray],
    smap: Mapping[str, tuple[str, str]],
    js: JointSet,
) -> dict[tuple[str, str], float]:
    """Flexion (degrees) of each straight-limb chain at the reference time, from bone
    vectors fitted to the whole recording (all tracked frames) and the IMU orientations
    at the reference time: far less noisy than the reference depth frames alone."""
    out: dict[tuple[str, str], float] = {}
    chains: dict[tuple[str, str], list[str]] = {}
    for name, chain in STRAIGHT_LIMBS.items():
        if name in q_world and name in smap:
            chains.setdefault(chain, []).append(name)
    for chain, names in chains.items():
        if len(names) != 2:
            continue
        vecs = []
        for name in sorted(names, key=lambda n: smap[n][0] != chain[0]):  # proximal first
            prox, dist = (js.role_index(r) for r in smap[name])
            b = _fit_segment_vector(tracked[:, dist] - tracked[:, prox],
                                    interp_quat(t, q_world[name], depth_times))
            if b is None:
                break
            vecs.append(quat_rotate(q_ref[name], b))
        if len(vecs) == 2:
            u, v = vecs
            out[chain] = float(np.degrees(np.arccos(np.clip(
                u @ v / (np.linalg.norm(u) * np.linalg.norm(v)), -1.0, 1.0))))
    return out


def _interp_positions(times: FloatArray, P: FloatArray, t: FloatArray) -> FloatArray:
    ok = np.isfinite(P).all(axis=1)
    if ok.sum() < 2:
        raise InsufficientDataError("the torso joint is tracked in fewer than two frames")
    return np.stack([np.interp(t, times[ok], P[ok, k]) for k in range(3)], axis=1)


def fuse_skeleton(
    skeleton: SkeletonSeries,
    imu_times: ArrayLike,
    orientations: Mapping[str, ArrayLike],
    calibration: PlankCalibration,
    reference_index: int | None = None,
    sensors: Mapping[str, tuple[str, str]] | None = None,
    reference_window: float = 0.5,
    bone_fit: Literal["standing", "all", "reference"] = "standing",
    max_standing_flexion_deg: float = 20.0,
) -> FusedSkeleton:
    """Build the fused skeleton (Kinect position, IMU rotations) on the IMU time grid.

    Args:
        skeleton: depth skeleton on the common clock (already synchronised).
        imu_times: ``(T,)`` times of the orientation series, common clock.
        orientations: sensor name -> ``(T, 4)`` filter output (sensor-to-earth).
        calibration: result of :func:`plank_calibration`.
        reference_index: reference depth frame; when ``None`` chosen by
            :func:`select_reference_frame` within the IMU time span among the frames
            whose window every IMU is still in (:func:`imu_still_frames`; depth stability
            alone, with a warning, if there is none).
        sensors: sensor -> (proximal role, distal role); default :data:`PAPER_SENSORS`.
            The chest sensor is required; limb sensors may be missing (their joints are
            then NaN).
        reference_window: seconds of depth frames around the reference frame averaged
            into the reference skeleton (the subject stands still then).
        bone_fit: how each joint's offset in its sensor frame is obtained. ``"reference"``
            is the paper's: from the reference skeleton alone, so the depth error of that
            one moment becomes a constant joint-angle offset. ``"all"`` fits it to every
            tracked depth frame of the recording (robust mean of the offset rotated into
            the sensor frame), which averages the random part of the depth errors out
            but not their systematic part (surface bias, pose-dependent fitting errors).
            ``"standing"`` (default) uses what the protocol guarantees: in the reference
            (standing) pose every limb of :data:`STRAIGHT_LIMBS` is straight, so both its
            segments point along the same root -> end direction (e.g. hip -> ankle,
            averaged over the still window); each segment's bone vector is that common
            direction seen from its sensor, times the segment length (median over all
            tracked frames). A depth error of the limb direction then turns both segments
            alike and the flexion angle stays exact to second order; the joint-angle
            offset left is the subject's deviation from straight limbs. Other joints
            (torso, hands, feet) and limbs bent by more than
            ``max_standing_flexion_deg`` in the averaged reference skeleton (a warning
            says so) use ``"all"``.
        max_standing_flexion_deg: largest knee/elbow flexion of the averaged reference
            skeleton still accepted as "straight".

    Returns:
        :class:`FusedSkeleton`; its skeleton's times are the IMU times inside the depth
        recording.

    Raises:
        InputError: missing chest sensor, shapes. InsufficientDataError: no usable
            reference frame or torso track.
    """
    smap = dict(sensors or PAPER_SENSORS)
    if bone_fit not in ("standing", "all", "reference"):
        raise InputError(f"bone_fit must be 'standing', 'all' or 'reference', got {bone_fit!r}")
    if "chest" not in orientations:
        raise InputError("the chest (torso) sensor is required for the fused skeleton")
    js: JointSet = skeleton.joint_set
    ti = np.asarray(imu_times, dtype=float)
    inside = (ti >= skeleton.times[0]) & (ti <= skeleton.times[-1])
    if inside.sum() < 2:
        raise InsufficientDataError("the IMU and depth recordings do not overlap in time; "
                                    "synchronise them first")
    t = ti[inside]
    q_world: dict[str, FloatArray] = {}
    for name, q in orientations.items():
        qa = np.asarray(q, dtype=float)
        if qa.shape != (len(ti), 4):
            raise InputError(f"orientation of {name!r} must have shape ({len(ti)}, 4), "
                             f"got {qa.shape}")
        if name in smap:
            q_world[name] = calibration.to_world(name, qa[inside])
    warnings: list[str] = []
    if reference_index is None:
        # the IMUs see motion far better than the depth tracker: only frames whose whole
        # window is still for every sensor are candidates (fallback: depth stability alone)
        still = imu_still_frames(t, q_world, skeleton.times, reference_window)
        try:
            reference_index = select_reference_frame(skeleton, window=reference_window,
                                                     t_min=t[0], t_max=t[-1],
                                                     candidates=still)
        except InsufficientDataError:
            reference_index = select_reference_frame(skeleton, window=reference_window,
                                                     t_min=t[0], t_max=t[-1])
            warnings.append("no moment where all IMUs were still while the depth skeleton "
                            "was tracked; the reference skeleton may include motion")
    t_ref = float(skeleton.times[reference_index])
    # Average the still window around the reference frame: depth noise in a single frame
    # would otherwise become a constant bone-direction (joint-angle) offset.
    near = np.abs(skeleton.times - t_ref) <= 0.5 * reference_window + 1e-9
    with np.errstate(invalid="ignore"):
        ref = np.nanmean(skeleton.tracked_positions()[near], axis=0) if near.sum() > 1 \
            else skeleton.positions[reference_index]
    ref = np.where(np.isfinite(ref), ref, skeleton.positions[reference_index])
    q_ref = {n: interp_quat(t, q, t_ref) for n, q in q_world.items()}
    tracked = skeleton.tracked_positions()
    inside_d = (skeleton.times >= t[0]) & (skeleton.times <= t[-1])
    tracked[~inside_d] = np.nan

    standing: dict[str, FloatArray] = {}
    if bone_fit == "standing":
        win = near & inside_d
        standing = _standing_bone_vectors(
            tracked, win, ref, smap, js, q_world,
            interp_quat_fn=lambda q: interp_quat(t, q, skeleton.times[win]),
            max_flexion_deg=max_standing_flexion_deg, warnings=warnings,
            flexion_estimate=_standing_flexion(tracked, skeleton.times, t, q_world, q_ref,
                                               smap, js))
    P = np.full((len(t), len(js.joints), 3), np.nan)
    torso = js.role_index(smap["chest"][0])
    P[:, torso] = _interp_positions(skeleton.times, skeleton.tracked_positions()[:, torso], t)
    for name in _ORDER:
        if name not in q_world:
            continue
        prox_role = smap[name][0]
        root = js.role_index(prox_role)
        if not np.isfinite(P[:, root]).all():
            continue  # the parent segment has no sensor
        carried = {js.role_index(r) for r in (smap[name][1], *_CARRIED.get(name, ()))}
        carried.discard(root)
        if bone_fit == "reference":
            # q(t) ⊗ q_ref*: world rotation of the segment since the reference frame
            dq = quat_mul(q_world[name], quat_conj(q_ref[name]))
            for j in sorted(carried):
                if np.isfinite(ref[j]).all() and np.isfinite(ref[root]).all():
                    P[:, j] = P[:, root] + quat_rotate(dq, ref[j] - ref[root])
        else:
            q_d = interp_quat(t, q_world[name], skeleton.times)
            for j in sorted(carried):
                if name in standing and j == js.role_index(smap[name][1]):
                    P[:, j] = P[:, root] + quat_rotate(q_world[name], standing[name])
                    continue
                b_s = _fit_segment_vector(tracked[:, j] - tracked[:, root], q_d)
                if b_s is None and np.isfinite(ref[j]).all() and np.isfinite(ref[root]).all():
                    b_s = quat_rotate(quat_conj(q_ref[name]), ref[j] - ref[root])
                if b_s is not None:
                    P[:, j] = P[:, root] + quat_rotate(q_world[name], b_s)
    states = np.where(np.isfinite(P).all(axis=2), TrackingState.TRACKED,
                      TrackingState.NOT_TRACKED).astype(np.uint8)
    fused = SkeletonSeries(t, P, states, js, {"source": "imu-depth fusion",
                                              "reference_time": t_ref})
    return FusedSkeleton(fused, reference_index, q_world, warnings)


def flexion_angles(skeleton: SkeletonSeries, tracked_only: bool = False) -> dict[str, FloatArray]:
    """Knee and elbow flexion (degrees, 0 = straight) from joint positions.

    Flexion is the angle between the proximal bone (hip→knee, shoulder→elbow) and the
    distal bone (knee→ankle, elbow→wrist), the same definition for depth, fused and
    reference skeletons.

    Args:
        skeleton: Any skeleton (time first axis) whose joint set has hip, knee, ankle,
            shoulder, elbow and wrist roles.
        tracked_only: Treat joints that are not TRACKED as missing.

    Returns:
        ``{"knee_left", "knee_right", "elbow_left", "elbow_right"}`` -> ``(T,)`` degrees
        (NaN where a joint is missing).
    """
    js = skeleton.joint_set
    P = skeleton.tracked_positions() if tracked_only else skeleton.positions
    out: dict[str, FloatArray] = {}
    for joint, (a, b, c) in {
        "knee_left": ("hip_left", "knee_left", "ankle_left"),
        "knee_right": ("hip_right", "knee_right", "ankle_right"),
        "elbow_left": ("shoulder_left", "elbow_left", "wrist_left"),
        "elbow_right": ("shoulder_right", "elbow_right", "wrist_right"),
    }.items():
        u = P[:, js.role_index(b)] - P[:, js.role_index(a)]
        v = P[:, js.role_index(c)] - P[:, js.role_index(b)]
        with np.errstate(invalid="ignore", divide="ignore"):
            cosang = np.sum(u * v, axis=1) / (np.linalg.norm(u, axis=1)
                                              * np.linalg.norm(v, axis=1))
        out[joint] = np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0)))
    return out

