"""ICP refinement of marker-based sensor poses on overlapping point clouds.

Open3D point-to-plane ICP with a robust (Tukey) kernel aligns a sensor's cloud to the
other sensors' clouds placed by the marker calibration. A refinement is KEPT only where it
helps and is trustworthy:

* the overlap is not degenerate: point-to-plane ICP on a floor-dominated scene cannot see
  in-plane sliding or turning about the floor normal (and two walls leave one direction
  free). The 6×6 point-to-plane information matrix (rotation scaled by the cloud radius)
  must have its smallest eigenvalue above ``min_eig_ratio`` of the largest; otherwise the
  refinement is refused (checked at the marker pose first — ICP is then not run at all —
  and again at the ICP result);
* the inlier RMSE drops by at least ``min_improvement`` (relative) without losing fitness;
* the correction agrees with the marker solution (≤ ``max_correction_m`` and
  ``max_correction_deg``): ICP must not drift a sensor away.

Every sensor gets an :class:`IcpReport` with fitness and inlier RMSE before/after.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.errors import InputError
from engine.geometry import rotation_angle, transform_points

if TYPE_CHECKING:  # open3d and scipy.spatial are imported where used: the server's start
    import open3d as o3d  # imports this module (calibration store) and needs neither

FloatArray = NDArray[np.float64]


@dataclass
class IcpResult:
    """One ICP alignment.

    Attributes:
        T: 4×4 transform applied to the source (source → target frame).
        fitness: Share of source points with a correspondence within ``max_dist``.
        inlier_rmse: RMS distance of those correspondences (m).
        fitness_before: Fitness at the initial transform.
        inlier_rmse_before: Inlier RMSE at the initial transform (m).
        eig_ratio: Smallest/largest eigenvalue of the point-to-plane information matrix.
    """

    T: FloatArray
    fitness: float
    inlier_rmse: float
    fitness_before: float
    inlier_rmse_before: float
    eig_ratio: float


@dataclass
class IcpReport:
    """ICP outcome for one sensor in :func:`refine_with_icp`.

    Attributes:
        sensor_id: Sensor id.
        accepted: Whether the refined pose replaced the marker pose.
        reason: Why not (or "improved").
        result: The ICP run (None when no overlap).
        correction_m: Size of the translation correction (m).
        correction_deg: Size of the rotation correction (deg).
    """

    sensor_id: str
    accepted: bool
    reason: str
    result: IcpResult | None
    correction_m: float = 0.0
    correction_deg: float = 0.0


def to_o3d(points: ArrayLike) -> o3d.geometry.PointCloud:
    """numpy (N, 3) → Open3D point cloud.

    Args:
        points: ``(N, 3)`` points, m.

    Returns:
        The Open3D cloud (float64 coordinates).
    """
    import open3d as o3d

    pc = o3d.geometry.PointCloud()
    pc.points = o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    return pc


def information_eig_ratio(src: FloatArray, dst: FloatArray, dst_normals: FloatArray,
                          max_dist: float) -> float:
    """Conditioning of point-to-plane ICP: λ_min/λ_max of Σ aaᵀ, a = [(p×n)/L, n].

    Args:
        src: ``(N, 3)`` source points (already in the target's frame), m.
        dst: ``(M, 3)`` target points, m.
        dst_normals: ``(M, 3)`` target normals.
        max_dist: Correspondence distance, m.

    Returns:
        The ratio in [0, 1] (near 0: a direction ICP cannot constrain, e.g. a bare floor;
        0 with fewer than six correspondences).
    """
    if len(src) == 0 or len(dst) == 0:
        return 0.0
    from scipy.spatial import cKDTree

    d, idx = cKDTree(dst).query(src, distance_upper_bound=max_dist)
    ok = np.isfinite(d)
    if ok.sum() < 6:
        return 0.0
    p = src[ok]
    n = dst_normals[idx[ok]]
    c = p.mean(axis=0)
    L = float(np.sqrt(np.mean(np.sum((p - c) ** 2, axis=1)))) or 1.0
    a = np.column_stack([np.cross(p - c, n) / L, n])
    w = np.linalg.eigvalsh(a.T @ a)
    return float(max(w[0], 0.0) / w[-1]) if w[-1] > 0 else 0.0


def icp_align(
    source: ArrayLike,
    target: ArrayLike,
    T_init: ArrayLike | None = None,
    voxel: float | None = 0.02,
    max_dist: float | None = None,
    iterations: int = 60,
    min_eig_ratio: float | None = None,
) -> IcpResult:
    """Point-to-plane ICP with a Tukey robust kernel, on voxel-downsampled clouds.

    Args:
        source: Source points (N, 3).
        target: Target points (M, 3).
        T_init: Initial source → target transform.
        voxel: Downsampling voxel (m); None keeps the clouds as they are (sparse clouds).
        max_dist: Correspondence distance (default 2.5 × voxel, or 5 cm).
        iterations: Maximum ICP iterations.
        min_eig_ratio: If given, ICP is not run when the overlap at ``T_init`` is already
            degenerate (information eigenvalue ratio below this): it would be refused
            anyway. The result then keeps ``T_init`` and the before-values.

    Returns:
        The transform (source → target frame) and the fitness and inlier RMSE (m) before
        and after (:class:`IcpResult`).

    Raises:
        InputError: empty clouds or bad voxel size.
    """
    import open3d as o3d

    if voxel is not None and voxel <= 0:
        raise InputError("ICP voxel size must be positive (metres)")
    src_np = np.asarray(source, dtype=np.float64).reshape(-1, 3)
    dst_np = np.asarray(target, dtype=np.float64).reshape(-1, 3)
    # Open3D's normals and ICP lose the clouds 1 km from the origin (fitness 0 on the real
    # feature clouds shifted 1-20 km: survey or georeferenced frames): work relative to
    # the target's centroid, T = S T' S⁻¹ with S the shift
    c = dst_np.mean(axis=0) if len(dst_np) else np.zeros(3)
    S = np.eye(4)
    S[:3, 3] = c
    S_inv = np.eye(4)
    S_inv[:3, 3] = -c
    s, t = to_o3d(src_np - c), to_o3d(dst_np - c)
    if voxel is not None:
        s, t = s.voxel_down_sample(voxel), t.voxel_down_sample(voxel)
    if len(s.points) < 10 or len(t.points) < 10:
        raise InputError("ICP needs at least 10 points in each cloud after downsampling")
    md = max_dist if max_dist is not None else (2.5 * voxel if voxel is not None else 0.05)
    t.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=1.5 * md, max_nn=30))
    T0 = S_inv @ (np.eye(4) if T_init is None else np.asarray(T_init, dtype=float)) @ S
    reg = o3d.pipelines.registration
    before = reg.evaluate_registration(s, t, md, T0)
    if min_eig_ratio is not None:
        r0 = information_eig_ratio(transform_points(T0, np.asarray(s.points)),
                                   np.asarray(t.points), np.asarray(t.normals), md)
        if r0 < min_eig_ratio:
            return IcpResult(S @ T0 @ S_inv, float(before.fitness), float(before.inlier_rmse),
                             float(before.fitness), float(before.inlier_rmse), r0)
    est = reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=md))
    out = reg.registration_icp(s, t, md, T0, est,
                               reg.ICPConvergenceCriteria(max_iteration=iterations))
    T = np.asarray(out.transformation, dtype=float)
    src_w = transform_points(T, np.asarray(s.points))
    ratio = information_eig_ratio(src_w, np.asarray(t.points), np.asarray(t.normals), md)
    return IcpResult(S @ T @ S_inv, float(out.fitness), float(out.inlier_rmse),
                     float(before.fitness), float(before.inlier_rmse), ratio)


def refine_with_icp(
    T_world_sensor: Mapping[str, FloatArray],
    clouds: Mapping[str, ArrayLike],
    voxel: float = 0.02,
    max_correction_m: float = 0.03,
    max_correction_deg: float = 1.0,
    min_improvement: float = 0.05,
    min_eig_ratio: float = 0.02,
    min_fitness: float = 0.2,
) -> tuple[dict[str, FloatArray], list[IcpReport]]:
    """Refine each sensor's pose by ICP of its cloud against the others' (world frame).

    Args:
        T_world_sensor: Marker-based poses.
        clouds: Sensor → points in that sensor's frame (e.g. a static depth frame).
        voxel: Downsampling voxel (m).
        max_correction_m: Largest accepted translation change (m).
        max_correction_deg: Largest accepted rotation change (deg).
        min_improvement: Smallest relative inlier-RMSE drop to accept.
        min_eig_ratio: Degeneracy threshold (see module docstring).
        min_fitness: Smallest overlap (fitness) to attempt a refinement.

    Returns:
        The poses (refined where accepted) and one report per sensor with a cloud.
    """
    poses = {s: np.asarray(T, dtype=float) for s, T in T_world_sensor.items()}
    world = {s: transform_points(poses[s], np.asarray(p, float).reshape(-1, 3))
             for s, p in clouds.items() if s in poses}
    reports: list[IcpReport] = []
    for sid in sorted(world):
        others = [world[o] for o in world if o != sid]
        if not others:
            reports.append(IcpReport(sid, False, "no other sensor's cloud to align to", None))
            continue
        try:
            r = icp_align(world[sid], np.concatenate(others), voxel=voxel,
                          min_eig_ratio=min_eig_ratio)
        except InputError as exc:
            reports.append(IcpReport(sid, False, str(exc), None))
            continue
        dt = float(np.linalg.norm(r.T[:3, 3]))
        dr = float(np.degrees(rotation_angle(r.T[:3, :3])))
        rep = IcpReport(sid, False, "", r, dt, dr)
        if r.fitness_before < min_fitness:
            rep.reason = ("too little overlap with the other sensors "
                          f"(fitness {r.fitness_before:.2f})")
        elif r.eig_ratio < min_eig_ratio:
            rep.reason = ("degenerate overlap (mostly floor/one plane): ICP cannot fix sliding "
                          "along it, refinement refused")
        elif r.inlier_rmse > (1 - min_improvement) * r.inlier_rmse_before or \
                r.fitness < r.fitness_before:
            rep.reason = "ICP did not improve the alignment"
        elif dt > max_correction_m or dr > max_correction_deg:
            rep.reason = (f"ICP moved the sensor {dt * 100:.1f} cm / {dr:.2f}° away from the "
                          "marker solution; kept the markers' pose")
        else:
            rep.accepted = True
            rep.reason = "improved"
            poses[sid] = r.T @ poses[sid]
            world[sid] = transform_points(r.T, world[sid])
        reports.append(rep)
    return poses, reports
