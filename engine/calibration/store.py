"""Saving, loading and comparing calibrations (versioned JSON files) — the bumped-tripod check.

A calibration is one JSON file ``calibration-v<version>.json`` in a folder; versions count
up from 1, so earlier calibrations stay listed and restorable. The file holds the poses
(4×4 row-major), residual tables, every observation's acceptance and reason, the time and
the format version.
"""

from __future__ import annotations

import json
import math
import re
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from engine.calibration.corners3d import Observation
from engine.calibration.pipeline import CalibrationResult, EdgeReport
from engine.errors import InputError
from engine.geometry import invert_transform, rotation_angle

FloatArray = NDArray[np.float64]

FORMAT = "gaitrig-calibration"
FORMAT_VERSION = 1
#: Bumped-tripod thresholds (issue 3): a sensor moved more than this needs recalibrating.
MOVED_POS_M = 0.01
MOVED_ROT_DEG = 0.5
_NAME = re.compile(r"^calibration-v(\d+)\.json$")


def _mat(T: FloatArray) -> list[list[float]]:
    return [[float(v) for v in row] for row in np.asarray(T, dtype=float)]


def _num(x: float) -> float | None:
    return None if not math.isfinite(x) else float(x)


def result_to_dict(result: CalibrationResult) -> dict[str, Any]:
    """JSON-ready dictionary of a calibration.

    Args:
        result: The calibration.

    Returns:
        Plain lists, numbers and strings (poses as nested 4×4 lists), with the format
        version.
    """
    return {
        "format": FORMAT, "format_version": FORMAT_VERSION,
        "version": result.version, "created": result.created,
        "created_iso": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(result.created)),
        "origin_marker": result.origin_marker, "dictionary": result.dictionary,
        "marker_sizes_m": {str(k): v for k, v in result.marker_sizes.items()},
        "T_world_sensor": {s: _mat(T) for s, T in result.T_world_sensor.items()},
        "T_world_sensor_chained": {s: _mat(T) for s, T in result.T_world_sensor_chained.items()},
        "T_world_sensor_joint": {s: _mat(T) for s, T in result.T_world_sensor_joint.items()},
        "T_world_marker": {str(m): _mat(T) for m, T in result.T_world_marker.items()},
        "sensor_residual_m": {s: _num(v) for s, v in result.sensor_residual_m.items()},
        "edges": [{"sensor": e.sensor_id, "marker": e.marker_id, "residual_m": _num(e.residual_m),
                   "procrustes_m": _num(e.procrustes_m), "distance_m": _num(e.distance_m),
                   "in_chain": e.in_chain} for e in result.edges],
        "observations": [o.to_dict() for o in result.observations],
        "meta": result.meta,
    }


def result_from_dict(d: dict[str, Any]) -> CalibrationResult:
    """Inverse of :func:`result_to_dict` (observations keep their summary, no corners).

    Args:
        d: A dict as :func:`result_to_dict` writes.

    Returns:
        The calibration.

    Raises:
        InputError: not a gaitrig calibration or a newer format.
    """
    if not isinstance(d, dict) or d.get("format") != FORMAT:
        raise InputError("not a gaitrig calibration file")
    if int(d.get("format_version", 0)) > FORMAT_VERSION:
        raise InputError("calibration written by a newer gaitrig; update gaitrig to read it")
    try:
        def T(v: Any) -> FloatArray:
            a = np.asarray(v, dtype=float)
            if a.shape != (4, 4):
                raise ValueError("pose is not 4×4")
            return a
        obs = [Observation(o["sensor"], int(o["marker"]), bool(o["accepted"]), o.get("reason", ""),
                           n_frames=int(o.get("frames", 0)),
                           n_frames_seen=int(o.get("frames_seen", 0)),
                           n_points=float(o.get("points", 0.0)),
                           plane_rms_m=(o["plane_rms_mm"] or float("nan")) / 1000
                           if o.get("plane_rms_mm") is not None else float("nan"),
                           distance_m=float(o["distance_m"]) if o.get("distance_m") is not None
                           else float("nan"))
               for o in d.get("observations", [])]
        nan = float("nan")
        return CalibrationResult(
            T_world_sensor={s: T(v) for s, v in d["T_world_sensor"].items()},
            T_world_sensor_chained={s: T(v) for s, v in d.get("T_world_sensor_chained",
                                                               {}).items()},
            T_world_marker={int(m): T(v) for m, v in d.get("T_world_marker", {}).items()},
            marker_sizes={int(k): float(v) for k, v in d.get("marker_sizes_m", {}).items()},
            sensor_residual_m={s: nan if v is None else float(v)
                               for s, v in d.get("sensor_residual_m", {}).items()},
            edges=[EdgeReport(e["sensor"], int(e["marker"]),
                              nan if e.get("residual_m") is None else float(e["residual_m"]),
                              nan if e.get("procrustes_m") is None else float(e["procrustes_m"]),
                              nan if e.get("distance_m") is None else float(e["distance_m"]),
                              bool(e.get("in_chain", False))) for e in d.get("edges", [])],
            observations=obs,
            origin_marker=int(d.get("origin_marker", 1)),
            dictionary=str(d.get("dictionary", "DICT_4X4_50")),
            created=float(d.get("created", 0.0)),
            version=None if d.get("version") is None else int(d["version"]),
            meta=dict(d.get("meta", {})),
            T_world_sensor_joint={s: T(v) for s, v in d.get("T_world_sensor_joint",
                                                             {}).items()},
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"calibration file is damaged: {exc}") from exc


def save_calibration(result: CalibrationResult, path: str | Path) -> Path:
    """Write ``result`` as JSON to ``path`` (atomically: temp file + rename).

    Args:
        result: The calibration.
        path: Destination file (its folder is created).

    Returns:
        ``path`` as a Path.
    """
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_suffix(p.suffix + ".tmp")
    tmp.write_text(json.dumps(result_to_dict(result), indent=1))
    tmp.replace(p)
    return p


def load_calibration(path: str | Path) -> CalibrationResult:
    """Read a calibration JSON file.

    Args:
        path: A file written by :func:`save_calibration`.

    Returns:
        The calibration (observations keep their summary, not their corners).

    Raises:
        InputError: unreadable, not JSON, or not a calibration.
    """
    try:
        d = json.loads(Path(path).read_text())
    except OSError as exc:
        raise InputError(f"cannot read calibration {path}: {exc.strerror}") from exc
    except json.JSONDecodeError as exc:
        raise InputError(f"calibration {Path(path).name} is not valid JSON") from exc
    return result_from_dict(d)


def list_versions(folder: str | Path) -> list[int]:
    """Saved calibration versions in ``folder``, ascending.

    Args:
        folder: The calibrations folder (may not exist yet).

    Returns:
        The version numbers (empty when none is saved).
    """
    f = Path(folder)
    if not f.is_dir():
        return []
    return sorted(int(m.group(1)) for p in f.iterdir() if (m := _NAME.match(p.name)))


def version_path(folder: str | Path, version: int) -> Path:
    """File of calibration ``version`` in ``folder``.

    Args:
        folder: The calibrations folder.
        version: Version number, from 1.

    Returns:
        The file's path (it may not exist).

    Raises:
        InputError: a version below 1.
    """
    if version < 1:
        raise InputError("calibration versions start at 1")
    return Path(folder) / f"calibration-v{int(version)}.json"


def save_version(result: CalibrationResult, folder: str | Path) -> int:
    """Save ``result`` as the next version in ``folder``.

    Args:
        result: The calibration (its ``version`` is set here).
        folder: The calibrations folder (created when missing).

    Returns:
        The new version number.
    """
    v = (list_versions(folder) or [0])[-1] + 1
    result.version = v
    save_calibration(result, version_path(folder, v))
    return v


def load_version(folder: str | Path, version: int | None = None) -> CalibrationResult:
    """Load calibration ``version`` (default: the latest) from ``folder``.

    Args:
        folder: The calibrations folder.
        version: Version number; None: the latest.

    Returns:
        The calibration.

    Raises:
        InputError: no such version.
    """
    vs = list_versions(folder)
    if not vs:
        raise InputError("no calibration saved yet: run a calibration first")
    v = vs[-1] if version is None else int(version)
    if v not in vs:
        raise InputError(f"calibration version {v} does not exist (saved: {vs})")
    return load_calibration(version_path(folder, v))


def pose_change(T_old: FloatArray, T_new: FloatArray) -> tuple[float, float]:
    """Translation (m) and rotation (deg) between two poses of one sensor.

    Args:
        T_old: 4×4 ``T_world_sensor`` before.
        T_new: 4×4 ``T_world_sensor`` after.

    Returns:
        ``(distance in m, angle in degrees)``.
    """
    d = invert_transform(T_old) @ np.asarray(T_new, dtype=float)
    return (float(np.linalg.norm(np.asarray(T_new)[:3, 3] - np.asarray(T_old)[:3, 3])),
            float(np.degrees(rotation_angle(d[:3, :3]))))


def check_moved(
    old: CalibrationResult | dict[str, FloatArray],
    new: CalibrationResult | dict[str, FloatArray],
    pos_m: float = MOVED_POS_M,
    rot_deg: float = MOVED_ROT_DEG,
) -> list[dict[str, Any]]:
    """Sensors whose pose changed by more than ``pos_m`` or ``rot_deg`` (bumped tripod).

    Args:
        old: The calibration in use (or sensor → T_world_sensor).
        new: A fresh estimate (e.g. from a quick re-detection).

    Returns:
        ``[{"sensor", "moved_m", "rotated_deg"}]`` for each moved sensor present in both.
    """
    a = old.T_world_sensor if isinstance(old, CalibrationResult) else old
    b = new.T_world_sensor if isinstance(new, CalibrationResult) else new
    out = []
    for s in sorted(set(a) & set(b)):
        dt, dr = pose_change(a[s], b[s])
        if dt > pos_m or dr > rot_deg:
            out.append({"sensor": s, "moved_m": dt, "rotated_deg": dr})
    return out
