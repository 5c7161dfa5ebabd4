"""Calibrations of the simulated avenue that tests build by hand: the true poses, and a
rig file with one tripod knocked (shared by the periodic-check, live and browser tests)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from engine.calibration.pipeline import CalibrationResult
from engine.geometry import make_transform, so3_exp
from engine.sim.rig import default_avenue_rig, save_rig

BUMP_M = 0.02
BUMP_DEG = 0.8


def truth_calibration(sensors: list[str]) -> CalibrationResult:
    """What a perfect calibration of the simulated avenue (seed 0) would save."""
    r = default_avenue_rig(0)
    return CalibrationResult(
        T_world_sensor={s: r.sensor(s).T_world_sensor.copy() for s in sensors},
        T_world_sensor_chained={}, T_world_marker={m.id: m.T_world_marker for m in r.markers},
        marker_sizes={m.id: m.size_m for m in r.markers}, sensor_residual_m={}, edges=[],
        observations=[])


def bumped_rig_file(path: Path, sensor: str) -> Path:
    """The avenue with ``sensor``'s tripod knocked 2 cm sideways and tilted 0.8°."""
    rig = default_avenue_rig(0)
    s = rig.sensor(sensor)
    T = s.T_world_sensor @ make_transform(so3_exp(np.radians([0.0, BUMP_DEG, 0.0])),
                                          [0.0, 0.0, 0.0])
    T[:3, 3] += [BUMP_M, 0.0, 0.0]
    s.T_world_sensor = T
    save_rig(rig, path)
    return path
