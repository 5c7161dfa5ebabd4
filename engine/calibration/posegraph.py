"""Joint least-squares pose-graph optimisation over every marker observation.

Beyond the seed paper's chaining (which uses one path per sensor and ignores every other
observation), all sensor poses ``T_world_sensor`` and marker poses ``T_world_marker``
(the origin marker fixed at identity) are estimated together so that every observed 3D
corner agrees with its prediction ``T_sensor_world · T_world_marker · corner_model``.

Each corner residual is weighted by that corner's noise (from
:mod:`engine.calibration.corners3d`: pixel noise moved onto the marker plane plus the
plane-fit uncertainty; it grows with distance and obliqueness). By default the weight is
isotropic (σ² = trace(Σ)/3): in the simulation the full anisotropic whitening trusted the
"good" directions of far observations too much (their errors are correlated across the
four corners, which a per-corner covariance cannot express) and was worse than chaining;
``anisotropic=True`` keeps it for study. A Huber loss limits the pull of a bad
observation. Poses are updated multiplicatively (``T = T₀ · exp(ξ)``) from the chained
estimate; the Jacobian is sparse (each observation touches one sensor and one marker),
which scipy exploits.

Optional floor prior: markers lying on the floor share marker 1's plane; each corner's
height above that plane is then a residual with standard deviation ``floor_sigma_m``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from engine.calibration.graph import Edge
from engine.calibration.markers import marker_model_corners
from engine.geometry import invert_transform, make_transform, so3_exp, transform_points

FloatArray = NDArray[np.float64]


@dataclass
class PoseGraphResult:
    """Result of :func:`optimise_poses`.

    Attributes:
        T_world_sensor: Optimised sensor poses.
        T_world_marker: Optimised marker poses (origin = identity).
        edge_residual_m: (sensor, marker) → RMS corner residual (m) after optimisation.
        sensor_residual_m: Sensor → RMS corner residual over its observations (m).
        cost: Final robust cost.
        n_iterations: Function evaluations used.
    """

    T_world_sensor: dict[str, FloatArray]
    T_world_marker: dict[int, FloatArray]
    edge_residual_m: dict[tuple[str, int], float]
    sensor_residual_m: dict[str, float]
    cost: float
    n_iterations: int


def _exp6(xi: FloatArray) -> FloatArray:
    return make_transform(so3_exp(xi[:3]), xi[3:])


def optimise_poses(
    edges: Sequence[Edge],
    T_world_sensor0: Mapping[str, FloatArray],
    T_world_marker0: Mapping[int, FloatArray],
    marker_sizes: Mapping[int, float],
    origin: int = 1,
    huber_scale: float = 3.0,
    floor_sigma_m: float | None = None,
    anisotropic: bool = False,
) -> PoseGraphResult:
    """Jointly refine sensor and marker poses from all observations.

    Args:
        edges: Observations with their corners and covariances.
        T_world_sensor0: Initial sensor poses (e.g. chained).
        T_world_marker0: Initial marker poses (every marker in ``edges``).
        marker_sizes: Marker id → edge length (m).
        origin: The marker fixed at the world origin.
        huber_scale: Huber threshold in whitened units (σ).
        floor_sigma_m: If given, markers are assumed on marker 1's floor plane with this
            height SD (m).
        anisotropic: Whiten by the full 3×3 corner covariance instead of its mean variance.

    Returns:
        The optimised poses and residual tables.
    """
    sensors = sorted(T_world_sensor0)
    markers = sorted(m for m in T_world_marker0 if m != origin)
    si = {s: k for k, s in enumerate(sensors)}
    mi = {m: len(sensors) + k for k, m in enumerate(markers)}
    n_par = 6 * (len(sensors) + len(markers))
    T0 = [np.asarray(T_world_sensor0[s], float) for s in sensors] + \
         [np.asarray(T_world_marker0[m], float) for m in markers]
    models = {m: marker_model_corners(marker_sizes[m]) for m in {e.marker_id for e in edges}}
    # whitening matrices: ‖Wᵀe‖² = eᵀΣ⁻¹e
    W = []
    for e in edges:
        Ws = []
        for k in range(4):
            S = e.obs.cov[k] + 1e-12 * np.eye(3)
            if anisotropic:
                Ws.append(np.linalg.cholesky(np.linalg.inv(S)).T)
            else:
                Ws.append(np.eye(3) / np.sqrt(np.trace(S) / 3.0))
        W.append(np.stack(Ws))
    n_res = 12 * len(edges) + (4 * len(markers) if floor_sigma_m else 0)

    def poses(x: FloatArray) -> list[FloatArray]:
        return [T0[k] @ _exp6(x[6 * k:6 * k + 6]) for k in range(len(T0))]

    # batched arrays: one row per edge (vectorised residuals; the solver calls fun often)
    e_s = np.array([si[e.sensor_id] for e in edges], dtype=int)
    e_m = np.array([mi.get(e.marker_id, -1) for e in edges], dtype=int)
    M = np.stack([models[e.marker_id] for e in edges])  # (E, 4, 3)
    O = np.stack([e.obs.corners for e in edges])  # (E, 4, 3)
    Wa = np.stack(W)  # (E, 4, 3, 3)
    floor_models = np.stack([marker_model_corners(marker_sizes[m]) for m in markers]) \
        if markers else np.zeros((0, 4, 3))

    def fun(x: FloatArray) -> FloatArray:
        P = np.stack(poses(x)) if T0 else np.zeros((0, 4, 4))
        Pinv = np.stack([invert_transform(T) for T in P[:len(sensors)]])
        allT = np.concatenate([P, np.eye(4)[None]])  # index -1 → origin (identity)
        T_sm = np.einsum("eij,ejk->eik", Pinv[e_s], allT[e_m])
        pred = np.einsum("eij,ekj->eki", T_sm[:, :3, :3], M) + T_sm[:, None, :3, 3]
        r = np.einsum("ekij,ekj->eki", Wa, pred - O).ravel()
        if not floor_sigma_m:
            return r
        Pm = P[len(sensors):]
        z = np.einsum("mj,mkj->mk", Pm[:, 2, :3], floor_models) + Pm[:, None, 2, 3]
        return np.concatenate([r, z.ravel() / floor_sigma_m])

    # scipy where it is used: the server's start imports this module and needs none
    from scipy.optimize import least_squares
    from scipy.sparse import lil_matrix

    sp = lil_matrix((n_res, n_par), dtype=int)
    for j, e in enumerate(edges):
        a = 6 * si[e.sensor_id]
        sp[12 * j:12 * j + 12, a:a + 6] = 1
        if e.marker_id != origin:
            b = 6 * mi[e.marker_id]
            sp[12 * j:12 * j + 12, b:b + 6] = 1
    if floor_sigma_m:
        base = 12 * len(edges)
        for k, m in enumerate(markers):
            b = 6 * mi[m]
            sp[base + 4 * k:base + 4 * k + 4, b:b + 6] = 1
    sol = least_squares(fun, np.zeros(n_par), jac_sparsity=sp, loss="huber",
                        f_scale=huber_scale, method="trf", x_scale="jac", xtol=1e-9,
                        ftol=1e-9, max_nfev=100)
    P = poses(sol.x)
    T_ws = {s: P[si[s]] for s in sensors}
    T_wm = {origin: np.eye(4), **{m: P[mi[m]] for m in markers}}
    edge_res: dict[tuple[str, int], float] = {}
    per_sensor: dict[str, list[float]] = {s: [] for s in sensors}
    for e in edges:
        T_sm = invert_transform(T_ws[e.sensor_id]) @ T_wm[e.marker_id]
        r = transform_points(T_sm, models[e.marker_id]) - e.obs.corners
        sq = np.sum(r * r, axis=1)
        edge_res[(e.sensor_id, e.marker_id)] = float(np.sqrt(sq.mean()))
        per_sensor[e.sensor_id].extend(sq.tolist())
    sens_res = {s: float(np.sqrt(np.mean(v))) if v else float("nan")
                for s, v in per_sensor.items()}
    return PoseGraphResult(T_ws, T_wm, edge_res, sens_res, float(sol.cost), int(sol.nfev))
