"""One call from raw IMU recordings and a depth skeleton to fused joint angles.

``process_imu_session`` chains the steps of seed 002: jump synchronisation, orientation
filtering (our filter, 9D or 6D), plank initialisation (found automatically when no time is
given), the fused skeleton and knee/elbow flexion for depth-only and fused skeletons.
``angles_csv`` renders the angles for download.
"""

from __future__ import annotations

import io
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.errors import InputError, InsufficientDataError
from engine.geometry import quat_conj, quat_rotate
from engine.imu.filter import FilterParams, orientation_filter
from engine.imu.fusion import (
    PAPER_SENSORS,
    FusedSkeleton,
    PlankCalibration,
    flexion_angles,
    fuse_skeleton,
    interp_quat,
    plank_calibration,
)
from engine.imu.io import ImuRecording
from engine.imu.sync import SyncResult, shift_recording, synchronize
from engine.skeleton import SkeletonSeries
from engine.wording import named

FloatArray = NDArray[np.float64]
#: ``(recording, nine_d) -> (quaternions ENU (T, 4), rest flags (T,))``
OrientationFn = Callable[[ImuRecording, bool], tuple[FloatArray, NDArray[np.bool_]]]


@dataclass
class ImuSessionResult:
    """Everything the IMU page shows.

    Attributes:
        sync: jump synchronisation (``None`` when the streams were already aligned).
        times: ``(T,)`` common IMU time grid (skeleton clock), s.
        orientations: sensor -> ``(T, 4)`` filter output on ``times`` (sensor-to-earth).
        calibration: plank calibration.
        fused: the fused skeleton.
        depth_times: ``(T_depth,)`` depth frame times, s.
        angles_depth: joint -> ``(T_depth,)`` flexion from the depth skeleton, degrees.
        angles_fused: joint -> ``(T_fused,)`` flexion from the fused skeleton, degrees.
        warnings: import/sync problems worth showing.
    """

    sync: SyncResult | None
    times: FloatArray
    orientations: dict[str, FloatArray]
    calibration: PlankCalibration
    fused: FusedSkeleton
    depth_times: FloatArray
    angles_depth: dict[str, FloatArray]
    angles_fused: dict[str, FloatArray]
    warnings: list[str] = field(default_factory=list)


def find_plank_time(
    times: ArrayLike,
    orientations: Mapping[str, ArrayLike],
    rest: Mapping[str, ArrayLike],
    max_spread_deg: float = 5.0,
    min_duration: float = 1.0,
) -> float:
    """Middle of the first period (≥ ``min_duration``) where every sensor rests and all
    sensors show the same tilt — the plank pose.

    Args:
        times: ``(T,)`` common time grid, s.
        orientations: Sensor name -> ``(T, 4)`` filter output (sensor-to-earth).
        rest: Sensor name -> ``(T,)`` rest flags of the filter.
        max_spread_deg: Largest tilt disagreement between sensors, degrees.
        min_duration: Shortest period, s.

    Returns:
        The plank time, s.

    Raises:
        InsufficientDataError: no such period.
    """
    t = np.asarray(times, dtype=float)
    names = list(orientations)
    ups = np.stack([quat_rotate(quat_conj(np.asarray(orientations[n], dtype=float)),
                                np.array([0.0, 0.0, 1.0])) for n in names], axis=1)
    med = np.median(ups, axis=1, keepdims=True)
    med /= np.linalg.norm(med, axis=-1, keepdims=True)
    spread = np.degrees(np.arccos(np.clip(np.sum(ups * med, axis=-1), -1.0, 1.0))).max(axis=1)
    ok = np.all(np.stack([np.asarray(rest[n], dtype=bool) for n in names], axis=1), axis=1)
    ok &= spread < max_spread_deg
    start = None
    for k in range(len(t) + 1):
        if k < len(t) and ok[k]:
            if start is None:
                start = k
        elif start is not None:
            if t[k - 1] - t[start] >= min_duration:
                return float(0.5 * (t[start] + t[k - 1]))
            start = None
    raise InsufficientDataError(
        "no plank pose found: no period where all IMUs rest with the same tilt; give the "
        "plank time explicitly")


def process_imu_session(
    recordings: Mapping[str, ImuRecording],
    skeleton: SkeletonSeries,
    *,
    plank_time: float | None = None,
    q_world_plank: ArrayLike = (1.0, 0.0, 0.0, 0.0),
    synchronise: bool = True,
    n_jumps: int = 5,
    use_magnetometer: bool = True,
    params: FilterParams | None = None,
    up: ArrayLike = (0.0, 0.0, 1.0),
    offline: bool = False,
    orientation: OrientationFn | None = None,
) -> ImuSessionResult:
    """Fuse IMU recordings with a depth skeleton (seed 002 end to end).

    Args:
        recordings: sensor name (keys of :data:`PAPER_SENSORS`, ``"chest"`` required) ->
            recording in its own clock.
        skeleton: depth skeleton, world frame, its clock is the common clock.
        plank_time: time (common clock) of the plank pose; found automatically if
            ``None``.
        q_world_plank: plank orientation in the world frame.
        synchronise: align the clocks by the jump series first.
        n_jumps: jumps performed for synchronisation.
        use_magnetometer: 9D fusion when every recording has a magnetometer.
        params: filter tuning.
        up: world up direction for the skeleton's jump detection.
        offline: use the filter's non-causal mode (bias known from the first sample,
            zero-phase inclination). Off by default: on the simulated protocol, whose
            recording ends while walking, the causal filter's fused knee angles are within
            0.2-0.4° of the truth, the offline mode's within 0.1-1° (it fades to single
            passes within a few seconds of the ends), although the offline mode is the
            more accurate one on the BROAD single-sensor trials.
        orientation: another orientation estimator, ``(recording, nine_d) ->
            (quaternions ENU (T, 4), rest flags (T,))``; default our filter with
            ``params``/``offline``.

    Returns:
        The synchronisation, per-sensor orientations on the common time grid (skeleton
        clock, s), the plank calibration, the fused skeleton and the knee/elbow flexion
        (degrees) of the depth and the fused skeleton (:class:`ImuSessionResult`).

    Raises:
        InputError: unknown sensor names or missing chest sensor.
        InsufficientDataError: no overlap, no jumps, no plank pose.
    """
    unknown = [n for n in recordings if n not in PAPER_SENSORS]
    if unknown:
        raise InputError(f"unknown {named('sensor name', unknown)}; name each recording's sensor "
                         f"as one of {', '.join(PAPER_SENSORS)}")
    if "chest" not in recordings:
        raise InputError("the chest sensor is required to fuse with a depth skeleton; name "
                         "one recording 'chest'")
    warnings = [f"{n}: {w}" for n, r in recordings.items() for w in r.warnings]
    sync = None
    recs = dict(recordings)
    if synchronise:
        sync = synchronize(recs, skeleton, n_jumps=n_jumps, reference="skeleton", up=up)
        recs = {n: shift_recording(r, sync.offsets[n]) for n, r in recs.items()}
        warnings += sync.warnings
    t0 = max(r.time[0] for r in recs.values())
    t1 = min(r.time[-1] for r in recs.values())
    if t1 - t0 < 1.0:
        raise InsufficientDataError("the IMU recordings overlap by less than one second")
    base = recs["chest"]
    grid = base.time[(base.time >= t0) & (base.time <= t1)]
    nine_d = use_magnetometer and all(r.mag is not None for r in recs.values())
    ori: dict[str, FloatArray] = {}
    rest: dict[str, FloatArray] = {}
    for n, r in recs.items():
        if orientation is not None:
            q, rs = orientation(r, nine_d)
        else:
            q, _, rs = orientation_filter(r.gyr, r.acc, r.mag if nine_d else None,
                                          frequency=r.frequency, params=params,
                                          offline=offline)
        ori[n] = interp_quat(r.time, q, grid)
        rest[n] = np.interp(grid, r.time, rs.astype(float)) > 0.5
    if plank_time is None:
        plank_time = find_plank_time(grid, ori, rest)
    calib = plank_calibration(grid, ori, plank_time, q_world_plank)
    fused = fuse_skeleton(skeleton, grid, ori, calib)
    warnings += fused.warnings
    return ImuSessionResult(sync, grid, ori, calib, fused, skeleton.times.copy(),
                            flexion_angles(skeleton, tracked_only=True),
                            flexion_angles(fused.skeleton), warnings)


def angles_csv(result: ImuSessionResult) -> str:
    """Joint angles as CSV text on the fused time grid.

    Columns: ``time_s`` then ``<joint>_fused_deg`` and ``<joint>_depth_deg`` per joint; the
    depth value is the nearest depth frame's (empty when no frame is within 1.5 frame
    periods).

    Args:
        result: The output of :func:`process_imu_session`.

    Returns:
        The CSV text (angles in degrees, 2 decimals; time s).
    """
    t = result.fused.skeleton.times
    depth_t = result.depth_times
    joints = list(result.angles_fused)
    out = io.StringIO()
    out.write("time_s," + ",".join(f"{j}_fused_deg,{j}_depth_deg" for j in joints) + "\n")
    if len(depth_t) > 1:
        k = np.clip(np.searchsorted(depth_t, t), 1, len(depth_t) - 1)
        k = np.where(np.abs(depth_t[k - 1] - t) < np.abs(depth_t[k] - t), k - 1, k)
        near = np.abs(depth_t[k] - t) <= 1.5 * float(np.median(np.diff(depth_t)))
    else:
        k = np.zeros(len(t), dtype=int)
        near = np.zeros(len(t), dtype=bool)

    def fmt(v: float) -> str:
        return "" if not np.isfinite(v) else f"{v:.2f}"

    for i in range(len(t)):
        row = [f"{t[i]:.4f}"]
        for j in joints:
            row.append(fmt(result.angles_fused[j][i]))
            row.append(fmt(result.angles_depth[j][k[i]]) if near[i] else "")
        out.write(",".join(row) + "\n")
    return out.getvalue()
