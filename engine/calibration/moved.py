"""Bumped-tripod check: re-detect the markers in fresh frames and compare sensor poses.

A sensor's pose is re-estimated from the markers it sees now, with the marker poses of
the active calibration held fixed: one weighted rigid Procrustes fit of every observed 3D
corner (sensor frame) to the same corner of the calibrated marker (world frame). No graph
and no chaining are needed — each sensor is checked on its own — so a quick capture of a
few frames per sensor is enough. Compared with the calibrated pose, a change above
1 cm or 0.5° (:data:`engine.calibration.store.MOVED_POS_M`, ``MOVED_ROT_DEG``) means the
tripod was bumped and the rig needs recalibrating.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from engine.calibration.corners3d import CornerParams, SensorFrames, observe_sensor
from engine.calibration.markers import marker_model_corners
from engine.calibration.pipeline import CalibrationResult
from engine.calibration.store import MOVED_POS_M, MOVED_ROT_DEG, pose_change
from engine.geometry import procrustes, transform_points

FloatArray = NDArray[np.float64]


@dataclass
class SensorCheck:
    """Outcome of the bumped-tripod check for one sensor.

    Attributes:
        sensor_id: Sensor id.
        status: ``"ok"``, ``"moved"`` or ``"unknown"`` (no calibrated marker usable now).
        moved_m: Position change against the calibration (m; NaN when unknown).
        rotated_deg: Rotation change (deg; NaN when unknown).
        markers: Calibrated markers used for the fresh pose.
        residual_m: RMS corner residual of the fresh pose (m).
        reason: What to do (empty when ok).
        T_world_sensor: The fresh pose (None when unknown).
    """

    sensor_id: str
    status: str
    moved_m: float = float("nan")
    rotated_deg: float = float("nan")
    markers: list[int] = field(default_factory=list)
    residual_m: float = float("nan")
    reason: str = ""
    T_world_sensor: FloatArray | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (mm and degrees for people).

        Returns:
            Status, position change (mm), rotation change (deg), the markers used, the
            residual (mm) and the reason; None for a value that is not known.
        """
        def num(x: float, k: float = 1.0, nd: int = 3) -> float | None:
            return round(x * k, nd) if np.isfinite(x) else None

        return {"sensor": self.sensor_id, "status": self.status,
                "moved_mm": num(self.moved_m, 1000.0, 2),
                "rotated_deg": num(self.rotated_deg, 1.0, 3), "markers": self.markers,
                "residual_mm": num(self.residual_m, 1000.0, 2), "reason": self.reason}


def check_sensor_frames(
    frames: SensorFrames,
    calibration: CalibrationResult,
    params: CornerParams | None = None,
    pos_m: float = MOVED_POS_M,
    rot_deg: float = MOVED_ROT_DEG,
) -> SensorCheck:
    """Re-estimate one sensor's pose from fresh frames and compare it with ``calibration``.

    Args:
        frames: Fresh colour + depth frames of the sensor.
        calibration: The saved calibration.
        params: 3D-corner thresholds (defaults when None).
        pos_m: Position change above which the sensor counts as moved, m.
        rot_deg: Rotation change above which it counts as moved, degrees.

    Returns:
        ``ok``, ``moved`` or ``unknown`` with the changes and what to do.

    Raises:
        InputError: frames without depth (see :func:`observe_sensor`).
    """
    sid = frames.sensor_id
    if sid not in calibration.T_world_sensor:
        return SensorCheck(sid, "unknown", reason=f"{sid} is not in calibration version "
                           f"{calibration.version}: calibrate the rig with this sensor")
    obs = observe_sensor(frames, calibration.marker_sizes, calibration.dictionary, params)
    use = [o for o in obs if o.accepted and o.marker_id in calibration.T_world_marker]
    if not use:
        seen = sorted(o.marker_id for o in obs)
        return SensorCheck(sid, "unknown", reason=(
            f"{sid} sees no calibrated marker now (seen: {seen or 'none'}): a marker was "
            "moved or covered, or the sensor turned away; check the room and recalibrate"))
    src, dst, w = [], [], []
    for o in use:
        model = marker_model_corners(calibration.marker_sizes[o.marker_id])
        src.append(o.corners)
        dst.append(transform_points(calibration.T_world_marker[o.marker_id], model))
        w.append(1.0 / np.maximum(np.trace(o.cov, axis1=1, axis2=2) / 3.0, 1e-12))
    S, D, W = np.concatenate(src), np.concatenate(dst), np.concatenate(w)
    T = procrustes(S, D, W)
    r = transform_points(T, S) - D
    rms = float(np.sqrt(np.mean(np.sum(r * r, axis=1))))
    dt, dr = pose_change(calibration.T_world_sensor[sid], T)
    moved = dt > pos_m or dr > rot_deg
    reason = (f"{sid} moved {dt * 100:.1f} cm / {dr:.2f}° since calibration version "
              f"{calibration.version} (limits {pos_m * 100:.0f} cm / {rot_deg}°): "
              "recalibrate before recording" if moved else "")
    return SensorCheck(sid, "moved" if moved else "ok", dt, dr,
                       sorted(o.marker_id for o in use), rms, reason, T)


def check_frames(frames: Sequence[SensorFrames], calibration: CalibrationResult,
                 params: CornerParams | None = None) -> list[SensorCheck]:
    """:func:`check_sensor_frames` for every sensor, sorted by id.

    Args:
        frames: Fresh colour + depth frames of each sensor.
        calibration: The saved calibration to compare with.
        params: 3D-corner thresholds (defaults when None).

    Returns:
        One :class:`SensorCheck` per sensor (``ok``, ``moved`` or ``unknown``).

    Raises:
        InputError: frames without depth.
    """
    return [check_sensor_frames(f, calibration, params)
            for f in sorted(frames, key=lambda f: f.sensor_id)]
