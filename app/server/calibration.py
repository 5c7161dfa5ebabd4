"""Calibration lifecycle on the server: versioned files under ``<data_dir>/calibrations``.

The latest version is the active calibration; restoring an older one saves it again as a
new version (history is never rewritten).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from engine.calibration.pipeline import CalibrationResult
from engine.calibration.store import (
    check_moved,
    list_versions,
    load_version,
    result_to_dict,
    save_version,
)
from engine.errors import InputError


def calibration_dir(data_dir: Path) -> Path:
    """Folder of the saved calibrations."""
    return Path(data_dir) / "calibrations"


def summary(res: CalibrationResult) -> dict[str, Any]:
    """One row of the calibration list."""
    worst = [v for v in res.sensor_residual_m.values() if math.isfinite(v)]
    return {
        "version": res.version, "created": res.created, "sensors": res.sensor_ids,
        "markers": sorted(res.T_world_marker),
        "max_sensor_residual_mm": round(max(worst) * 1000, 2) if worst else None,
        "rejected": len(res.rejected),
    }


def list_calibrations(data_dir: Path) -> list[dict[str, Any]]:
    """Summaries of all versions, newest first."""
    folder = calibration_dir(data_dir)
    return [summary(load_version(folder, v)) for v in reversed(list_versions(folder))]


def get_calibration(data_dir: Path, version: int | None = None) -> dict[str, Any]:
    """Full JSON of one version (default: the active, i.e. latest)."""
    return result_to_dict(load_version(calibration_dir(data_dir), version))


def save(data_dir: Path, res: CalibrationResult) -> int:
    """Save a new calibration; returns its version."""
    return save_version(res, calibration_dir(data_dir))


def restore(data_dir: Path, version: int) -> int:
    """Make an older version active again by saving it as the newest version."""
    folder = calibration_dir(data_dir)
    res = load_version(folder, version)
    res.meta = {**res.meta, "restored_from": version}
    return save_version(res, folder)


def check_pose_change(data_dir: Path, poses: dict[str, Any]) -> list[dict[str, Any]]:
    """Bumped-tripod check of fresh sensor poses against the active calibration.

    Raises:
        InputError: poses that are not 4×4 matrices.
    """
    new = {}
    for s, T in poses.items():
        a = np.asarray(T, dtype=float)
        if a.shape != (4, 4) or not np.isfinite(a).all():
            raise InputError(f"pose of {s!r} must be a 4×4 matrix of numbers")
        new[str(s)] = a
    return check_moved(load_version(calibration_dir(data_dir)), new)


def simulate_and_save(data_dir: Path, seed: int, frames: int) -> dict[str, Any]:
    """Run the calibration on the simulated avenue, save it, return it with true errors."""
    from engine.calibration.pipeline import calibrate_frames
    from engine.calibration.simcapture import pose_errors, simulate_capture
    from engine.sim.rig import default_avenue_rig

    rig = default_avenue_rig(seed)
    res = calibrate_frames(simulate_capture(rig, frames, seed),
                           {m.id: m.size_m for m in rig.markers})
    res.meta["source"] = f"simulation (seed {seed}, {frames} frames)"
    version = save(data_dir, res)
    doc = result_to_dict(res)
    doc["version"] = version
    doc["true_errors"] = pose_errors(res, rig)
    return doc


def active_poses(data_dir: Path) -> dict[str, dict[str, Any]]:
    """Sensor poses of the active calibration, in the form the analysis uses
    (``{node: {"T_world_sensor", "source", "calibration_version", "residual_mm"}}``);
    empty when nothing is calibrated."""
    folder = calibration_dir(data_dir)
    if not list_versions(folder):
        return {}
    res = load_version(folder)
    out: dict[str, dict[str, Any]] = {}
    for s, T in res.T_world_sensor.items():
        r = res.sensor_residual_m.get(s, float("nan"))
        out[s] = {"T_world_sensor": np.asarray(T).tolist(), "source": "calibration",
                  "calibration_version": str(res.version),
                  "residual_mm": round(r * 1000, 3) if math.isfinite(r) else None}
    return out


def _set_pose(session: Any, T: list[list[float]]) -> None:
    session.sensor = session.sensor.model_copy(update={"T_world_sensor": T})


def apply_to_registry(registry: Any, data_dir: Path) -> list[str]:
    """Give every known node the active calibration's pose (replacing the pose the node
    reported), and keep doing so for nodes that (re)connect later.

    Returns:
        Ids of the nodes that got a calibrated pose now.
    """
    poses = active_poses(data_dir)
    applied = []
    for node_id, s in registry.nodes.items():
        if node_id in poses:
            _set_pose(s, poses[node_id]["T_world_sensor"])
            applied.append(node_id)
    listeners = registry.listeners
    if not any(getattr(cb, "_gaitrig_calibration", False) for cb in listeners):
        def on_connect(session: Any) -> None:
            p = active_poses(data_dir).get(session.id)
            if p is not None:
                _set_pose(session, p["T_world_sensor"])
        on_connect._gaitrig_calibration = True  # type: ignore[attr-defined]
        listeners.append(on_connect)
    return sorted(applied)
