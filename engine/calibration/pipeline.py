"""Spatial calibration end to end: observations → graph → chaining → joint optimisation.

``calibrate_frames`` takes colour + depth frames per sensor; ``calibrate`` takes
observations (e.g. from :func:`engine.calibration.corners3d.observe_sensor` run on each
node). Both return a :class:`CalibrationResult` with the chained (paper) and optimised
poses, residual tables, every observation with its acceptance and reason, and the graph
edges for display. ``calibrate_frames`` then refines the optimised poses by ICP of the
sensors' (temporal-median) depth clouds (:func:`engine.calibration.icp.refine_with_icp`),
keeping a refinement only where it improves the overlap and is not degenerate; every
sensor's ICP outcome is in ``meta["icp"]``, every sensor's camera model (with its lens
distortion) in ``meta["cameras"]``. Saving, loading and the bumped-tripod check are in
:mod:`engine.calibration.store`.
"""

from __future__ import annotations

import os
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from engine.calibration.corners3d import (
    CornerParams,
    Observation,
    SensorFrames,
    observe_sensor,
    robust_mean_image,
)
from engine.calibration.graph import build_edges, chain_poses, check_connectivity
from engine.calibration.icp import IcpReport, refine_with_icp
from engine.calibration.markers import DEFAULT_DICTIONARY, dictionary_name
from engine.calibration.posegraph import optimise_poses
from engine.errors import CalibrationError, InputError
from engine.pointcloud import depth_to_points, jump_edge_pixels, pixel_ray_table
from engine.wording import count

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
        T_world_sensor_joint: Poses of the joint optimisation before ICP (empty when ICP
            was not run; ``T_world_sensor`` then is the joint optimisation).
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
    T_world_sensor_joint: dict[str, FloatArray] = field(default_factory=dict)

    @property
    def sensor_ids(self) -> list[str]:
        """Ids of the calibrated sensors, sorted."""
        return sorted(self.T_world_sensor)

    @property
    def rejected(self) -> list[Observation]:
        """The observations that were not used, each with its ``reason``."""
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

    Returns:
        The calibration: ``T_world_sensor`` per sensor (jointly optimised), the
        paper's chained estimate, marker poses, per-sensor residuals (m) and the edge table.

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
    icp: bool = True,
) -> CalibrationResult:
    """Calibrate from colour + depth frames of every sensor (detect, 3D corners, solve, ICP).

    Args:
        frames: Colour + depth frames and camera model of every sensor.
        marker_sizes: Marker id → edge length (m), or one size for all.
        origin_marker: Marker defining the world frame.
        dictionary: Marker dictionary.
        params: 3D-corner thresholds.
        floor_sigma_m: Floor prior (see :func:`calibrate`).
        icp: Refine the optimised poses by ICP of the depth clouds (kept only where it
            improves; see :func:`engine.calibration.icp.refine_with_icp`).

    Returns:
        The calibration: ``T_world_sensor`` per sensor (world: origin marker, Z up), the
        paper's chained estimate, marker poses, residuals, every observation with the
        reason of a rejection, and the ICP reports in ``meta["icp"]``.

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

    def per_sensor(f: SensorFrames) -> tuple[list[Observation], FloatArray | None]:
        return (observe_sensor(f, known, dictionary, params),
                static_cloud(f) if icp else None)

    # sensors are independent (each has its own RANSAC seed): one worker per core, since
    # OpenCV and numpy release the GIL for most of the work
    workers = max(1, min(len(frames), os.cpu_count() or 1))
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="calib") as ex:
        done = list(ex.map(per_sensor, frames))
    obs = [o for sensor_obs, _ in done for o in sensor_obs]
    if not obs:
        _no_markers_anywhere(frames, dictionary)
    res = calibrate(obs, marker_sizes, ids, origin_marker, floor_sigma_m, dictionary)
    res.meta["cameras"] = {f.sensor_id: camera_model_dict(f) for f in frames}
    if icp:
        apply_icp(res, {f.sensor_id: c for f, (_, c) in zip(frames, done, strict=True)
                        if c is not None})
    return res


def camera_model_dict(frames: SensorFrames) -> dict[str, Any]:
    """JSON-ready camera model a sensor's observations were computed with.

    Kept with the calibration in ``meta["cameras"]``: each image's size, 3×3 K and OpenCV
    distortion (``[]``: none, a pinhole).

    Args:
        frames: The sensor's frames and camera model.

    Returns:
        ``{"color" | "depth": {"size": [w, h], "K": 3×3 lists, "dist": [...]}}`` for the
        images the sensor has.
    """
    from engine.calibration.corners3d import _intr

    out: dict[str, Any] = {}
    for key, obj, imgs in (("color", frames.color_intrinsics, frames.colors),
                           ("depth", frames.depth_intrinsics, frames.depths)):
        if imgs is None or len(imgs) == 0:
            continue
        intr = _intr(obj, np.asarray(imgs[0]).shape)
        out[key] = {"size": [intr.width, intr.height], "K": intr.K.tolist(),
                    "dist": [float(x) for x in intr.dist]}
    return out


def _no_markers_anywhere(frames: Sequence[SensorFrames], dictionary: str) -> None:
    """CalibrationError naming the dictionary the printed markers are from, when no sensor
    saw one of ``dictionary`` but another dictionary finds markers in a sensor's image;
    returns otherwise (the usual error follows)."""
    from engine.calibration.detect import find_dictionary

    for f in frames:
        if not len(f.colors):
            continue
        found = find_dictionary(robust_mean_image(f.colors), exclude=dictionary)
        if found is not None:
            raise CalibrationError(
                f"no sensor sees a {dictionary_name(dictionary)} marker, but {f.sensor_id} "
                f"sees {count(found[1], found[0] + ' marker')}: the markers were printed from "
                f"another dictionary; set the dictionary to {found[0]} (or print "
                f"{dictionary_name(dictionary)} markers) and capture again",
                unreachable=[g.sensor_id for g in frames])


#: Voxel (m) of the ICP refinement's clouds.
ICP_VOXEL_M = 0.02


def static_cloud(frames: SensorFrames, max_frames: int = 9, stride: int = 2) -> FloatArray:
    """The sensor's static scene as points in its (depth camera) frame.

    The per-pixel temporal median of up to ``max_frames`` depth frames (removes noise,
    dropouts and a person walking through) on every ``stride``-th pixel, without the
    pixels behind a depth edge (:func:`engine.pointcloud.jump_edge_pixels`: time-of-flight
    flying pixels), unprojected with the depth intrinsics (1 cm spacing at 2.5 m: ample
    for the 2 cm ICP voxel).

    Args:
        frames: The sensor's depth frames and camera model.
        max_frames: Most frames in the median.
        stride: Pixel step in both image directions.

    Returns:
        ``(N, 3)`` points, m (OpenCV camera frame).
    """
    from engine.calibration.corners3d import _intr

    if frames.depths is None or len(frames.depths) == 0:
        return np.zeros((0, 3))
    n = len(frames.depths)
    idx = np.unique(np.linspace(0, n - 1, min(max_frames, n)).round().astype(int))
    full = np.asarray(frames.depths[0])
    stack = np.stack([np.asarray(frames.depths[i], dtype=np.float64)[::stride, ::stride]
                      for i in idx])
    stack[stack <= 0] = np.nan
    # median only where some frame has a return (pixels without any stay 0 = no depth);
    # not via catch_warnings, which is not thread-safe and sensors run in parallel
    seen = np.isfinite(stack).any(axis=0)
    med = np.zeros(stack.shape[1:], dtype=np.float64)
    med[seen] = np.nanmedian(stack[:, seen], axis=0)
    intr = _intr(frames.depth_intrinsics, full.shape)
    rays = pixel_ray_table(intr)
    if rays.shape[:2] == full.shape:
        # a time-of-flight pixel across a depth edge (a table's rim, a door frame) reads
        # between both surfaces in every frame, so the median keeps it: points floating
        # along the line of sight that ICP would pull towards
        med[jump_edge_pixels(med / frames.depth_scale, rays[::stride, ::stride])] = 0.0
    img = np.zeros(full.shape, dtype=np.float64)
    img[::stride, ::stride] = med
    pts, idx_flat = depth_to_points(img, intr, frames.depth_scale, max_depth=8.0,
                                    stride=stride)
    if intr.dist and np.any(intr.dist_array != 0):
        # a depth lens (Azure Kinect): the pinhole points' depths along undistorted rays
        from engine.calibration.corners3d import corner_rays

        v, u = np.divmod(idx_flat, full.shape[1])
        pts = corner_rays(np.column_stack([u, v]), intr) * pts[:, 2:3]
    return pts


def _voxel(points: FloatArray, voxel: float) -> FloatArray:
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, float)))
    return np.asarray(pc.voxel_down_sample(voxel).points)


def icp_report_dict(r: IcpReport) -> dict[str, Any]:
    """JSON-ready ICP outcome of one sensor.

    Args:
        r: The report.

    Returns:
        Sensor, accepted, reason, the correction (mm, deg) and, when ICP ran, the
        fitness and inlier RMSE (mm) before and after, and the conditioning.
    """
    d: dict[str, Any] = {"sensor": r.sensor_id, "accepted": r.accepted, "reason": r.reason,
                         "correction_mm": round(r.correction_m * 1000, 3),
                         "correction_deg": round(r.correction_deg, 4)}
    if r.result is not None:
        d.update(fitness_before=round(r.result.fitness_before, 4),
                 fitness=round(r.result.fitness, 4),
                 inlier_rmse_before_mm=round(r.result.inlier_rmse_before * 1000, 3),
                 inlier_rmse_mm=round(r.result.inlier_rmse * 1000, 3),
                 eig_ratio=round(r.result.eig_ratio, 5))
    return d


def apply_icp(res: CalibrationResult, clouds: Mapping[str, FloatArray],
              voxel: float = ICP_VOXEL_M) -> list[IcpReport]:
    """Refine ``res``'s sensor poses by ICP in place (kept only where it improves).

    The joint-optimisation poses are kept in ``res.T_world_sensor_joint``, the reports in
    ``res.meta["icp"]``. Sensors without a usable cloud keep their pose (with a reason).

    Args:
        res: The calibration to refine (its ``T_world_sensor`` are updated).
        clouds: Sensor id -> ``(N, 3)`` static points in that sensor's depth camera frame
            (m), e.g. from :func:`static_cloud`.
        voxel: Voxel edge of the downsampling, m.

    Returns:
        One ICP report per calibrated sensor (accepted or not, and why).
    """
    # each cloud is voxel-downsampled once here (ICP downsamples the merged others again)
    use = {s: _voxel(p, voxel) for s, p in clouds.items()
           if s in res.T_world_sensor and len(p) > 0}
    res.T_world_sensor_joint = {s: np.asarray(T, float).copy()
                                for s, T in res.T_world_sensor.items()}
    poses, reports = refine_with_icp(res.T_world_sensor, use, voxel=voxel)
    for s in sorted(set(res.T_world_sensor) - set(use)):
        reports.append(IcpReport(s, False, "no depth points for ICP", None))
    res.T_world_sensor = {s: np.asarray(T, float) for s, T in poses.items()}
    res.meta["icp"] = [icp_report_dict(r) for r in sorted(reports, key=lambda r: r.sensor_id)]
    return reports
