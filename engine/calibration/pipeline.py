"""Spatial calibration end to end: observations → graph → chaining → joint optimisation.

``calibrate_frames`` takes colour + depth frames per sensor; ``calibrate`` takes
observations (e.g. from :func:`engine.calibration.corners3d.observe_sensor` run on each
node). Both return a :class:`CalibrationResult` with the chained (paper) and optimised
poses, residual tables, every observation with its acceptance and reason, and the graph
edges for display. Saving, loading and the bumped-tripod check are in
:mod:`engine.calibration.store`.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from engine.calibration.corners3d import CornerParams, Observation, SensorFrames, observe_sensor
from engine.calibration.graph import build_edges, chain_poses, check_connectivity
from engine.calibration.markers import DEFAULT_DICTIONARY
from engine.calibration.posegraph import optimise_poses
from engine.errors import CalibrationError, InputError

FloatArray = NDArray[np.float64]

#: Default floor prior: calibration markers lie on the floor, in marker 1's plane, to
#: ± 2 mm (a flat lab floor). It steadies the far sensors (simulation: RMS position error
#: 2.2 → 1.6 mm); pass ``floor_sigma_m=None`` for markers not on one floor.
FLOOR_SIGMA_M = 0.002


@dataclass
class EdgeReport:
    """A sensor↔marker edge for the residual table and the 3D graph.

    Attributes:
        sensor_id: Sensor id.
        marker_id: Marker id.
        residual_m: RMS corner residual with the optimised poses (m).
        procrustes_m: RMS residual of the single-observation Procrustes fit (m).
        distance_m: Sensor–marker distance (m).
        in_chain: Whether the chained estimate used this edge.
    """

    sensor_id: str
    marker_id: int
    residual_m: float
    procrustes_m: float
    distance_m: float
    in_chain: bool


@dataclass
class CalibrationResult:
    """A spatial calibration.

    Attributes:
        T_world_sensor: Final pose per sensor (optimised).
        T_world_sensor_chained: The seed paper's shortest-path chained estimate.
        T_world_marker: Marker poses (optimised; origin marker = identity).
        marker_sizes: Marker id → edge length (m).
        sensor_residual_m: Sensor → RMS corner residual (m).
        edges: Per-edge residual table.
        observations: Every observation, accepted or rejected with its reason.
        origin_marker: The marker defining the world.
        dictionary: Marker dictionary.
        created: Unix time of the computation.
        version: Calibration version (set by the store when saved).
        meta: Free-form extra information (ICP reports, notes).
    """

    T_world_sensor: dict[str, FloatArray]
    T_world_sensor_chained: dict[str, FloatArray]
    T_world_marker: dict[int, FloatArray]
    marker_sizes: dict[int, float]
    sensor_residual_m: dict[str, float]
    edges: list[EdgeReport]
    observations: list[Observation]
    origin_marker: int = 1
    dictionary: str = DEFAULT_DICTIONARY
    created: float = field(default_factory=time.time)
    version: int | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def sensor_ids(self) -> list[str]:
        return sorted(self.T_world_sensor)

    @property
    def rejected(self) -> list[Observation]:
        return [o for o in self.observations if not o.accepted]


def _sizes(marker_sizes: Mapping[int, float] | float, ids: Sequence[int]) -> dict[int, float]:
    if isinstance(marker_sizes, int | float):
        if not marker_sizes > 0:
            raise InputError(f"marker size must be positive (metres), got {marker_sizes}")
        return {int(i): float(marker_sizes) for i in ids}
    out = {int(k): float(v) for k, v in marker_sizes.items()}
    bad = [k for k, v in out.items() if not v > 0]
    if bad:
        raise InputError(f"marker sizes must be positive (metres); check markers {bad}")
    return out


def calibrate(
    observations: Sequence[Observation],
    marker_sizes: Mapping[int, float] | float,
    sensor_ids: Sequence[str] | None = None,
    origin_marker: int = 1,
    floor_sigma_m: float | None = FLOOR_SIGMA_M,
    dictionary: str = DEFAULT_DICTIONARY,
) -> CalibrationResult:
    """Calibrate from per-sensor marker observations.

    Args:
        observations: Observations of every sensor (accepted and rejected).
        marker_sizes: Marker id → edge length (m), or one size for all.
        sensor_ids: Sensors to calibrate (default: those with observations). A sensor
            without any observation is reported as unreachable.
        origin_marker: Marker defining the world frame.
        floor_sigma_m: Floor prior for the optimisation (see
            :func:`engine.calibration.posegraph.optimise_poses`); None = off (markers
            not all on one floor).
        dictionary: Marker dictionary (recorded with the result).

    Raises:
        CalibrationError: a sensor has no chain of markers to the origin marker
            (``.unreachable`` lists them), or no sensor is given.
        InputError: bad marker sizes.
    """
    sids = sorted(set(sensor_ids) if sensor_ids is not None
                  else {o.sensor_id for o in observations})
    if not sids:
        raise CalibrationError("no sensors to calibrate: no observations were given")
    sizes = _sizes(marker_sizes, sorted({o.marker_id for o in observations}))
    obs = list(observations)
    for o in obs:
        if o.accepted and o.marker_id not in sizes:
            o.accepted = False
            o.reason = f"marker {o.marker_id} is not in the marker list (unknown size)"
    edges = build_edges([o for o in obs if o.sensor_id in sids], sizes)
    check_connectivity(sids, edges, origin_marker, rejected=obs)
    T_ws0, T_wm0, used = chain_poses(sids, edges, origin_marker)
    # markers only reachable through unreachable sensors cannot exist here (connected)
    pg = optimise_poses(edges, T_ws0, T_wm0, sizes, origin_marker, floor_sigma_m=floor_sigma_m)
    used_set = set(used)
    reports = [
        EdgeReport(e.sensor_id, e.marker_id, pg.edge_residual_m[(e.sensor_id, e.marker_id)],
                   e.residual_m, e.obs.distance_m, (e.sensor_id, e.marker_id) in used_set)
        for e in edges
    ]
    return CalibrationResult(
        T_world_sensor=pg.T_world_sensor, T_world_sensor_chained=T_ws0,
        T_world_marker=pg.T_world_marker, marker_sizes=sizes,
        sensor_residual_m=pg.sensor_residual_m, edges=reports, observations=obs,
        origin_marker=origin_marker, dictionary=dictionary,
        meta={"optimiser": {"cost": pg.cost, "evaluations": pg.n_iterations,
                            "floor_sigma_m": floor_sigma_m}},
    )


def calibrate_frames(
    frames: Sequence[SensorFrames],
    marker_sizes: Mapping[int, float] | float,
    origin_marker: int = 1,
    dictionary: str = DEFAULT_DICTIONARY,
    params: CornerParams | None = None,
    floor_sigma_m: float | None = FLOOR_SIGMA_M,
) -> CalibrationResult:
    """Calibrate from colour + depth frames of every sensor (detect, 3D corners, solve).

    Raises:
        InputError: a sensor without depth frames, mismatched frame counts.
        CalibrationError: see :func:`calibrate`.
    """
    if not frames:
        raise InputError("no sensor frames given")
    ids = [f.sensor_id for f in frames]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise InputError(f"sensor ids appear twice: {dup}")
    known = None if isinstance(marker_sizes, int | float) else dict(marker_sizes)
    obs: list[Observation] = []
    for f in frames:
        obs.extend(observe_sensor(f, known, dictionary, params))
    return calibrate(obs, marker_sizes, ids, origin_marker, floor_sigma_m, dictionary)
