"""Compare two users' motions joint by joint, with dynamic time warping (DTW).

Both series should be in a common frame — normally each site's KSCC universal frame
(``engine.kscc``), where two users standing anywhere and facing any way start at the same
place facing +X.

Similarity score. ``similarity = 100 · exp(−d̄ / scale_m)`` where ``d̄`` is the mean
joint distance (m) after time alignment, over all aligned frame pairs and joints, and
``scale_m`` defaults to 0.10 m. Range (0, 100]: 100 = identical; 90 ≈ 1 cm apart on
average; 61 = 5 cm (roughly the Kinect's own noise and the paper's KSCC agreement
limit); 37 = 10 cm; below 14 the motions differ by more than 20 cm on average.

Joint sets. Two sites with different sensors (e.g. Kinect v1 vs v2) have different joint
sets; comparing them raises :class:`~engine.errors.InputError` unless ``by_role=True``,
which compares the joints both sets share by semantic role (``JointSet.roles``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.errors import InputError, InsufficientDataError
from engine.kscc import check_metres
from engine.skeleton import JointSet, SkeletonSeries, TrackingState

FloatArray = NDArray[np.float64]


def common_joints(a: JointSet, b: JointSet, by_role: bool = False
                  ) -> tuple[list[str], NDArray[np.int64], NDArray[np.int64]]:
    """Names and indices of the joints compared between joint sets ``a`` and ``b``.

    Args:
        a: First joint set.
        b: Second joint set.
        by_role: Map joints by semantic role (compare e.g. Kinect v2 with Azure Kinect).

    Returns:
        ``(names, idx_a, idx_b)``: joint names (role names when mapped by role) and
        their indices in each set.

    Raises:
        InputError: different joint sets and ``by_role`` is false, or no role in common.
    """
    if a.name == b.name:
        idx = np.arange(len(a.joints), dtype=np.int64)
        return list(a.joints), idx, idx.copy()
    if not by_role:
        raise InputError(
            f"the two sites use different joint sets ({a.name}, {len(a.joints)} joints vs "
            f"{b.name}, {len(b.joints)} joints); compare with by_role=True to use the joints "
            "they share by role"
        )
    roles = [r for r in a.roles if r in b.roles]
    if not roles:
        raise InputError(f"{a.name} and {b.name} share no joint roles")
    return (roles, np.array([a.role_index(r) for r in roles], dtype=np.int64),
            np.array([b.role_index(r) for r in roles], dtype=np.int64))


def _usable(s: SkeletonSeries) -> FloatArray:
    p = s.positions.copy()
    p[s.states == TrackingState.NOT_TRACKED] = np.nan
    return p


#: Largest DTW problem (N·M cells, ≈ 200 MB of float64 for the accumulated cost).
MAX_DTW_CELLS = 25_000_000


def frame_costs(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """``(N, M)`` mean joint distance between every frame of ``a`` (N, J, 3) and ``b``.

    Joints missing (NaN) in either frame are left out of that pair's mean; a pair with
    no joint in common costs ``inf``.

    Args:
        a: ``(N, J, 3)`` joint positions, m.
        b: ``(M, J, 3)`` joint positions of the same joints, m.

    Returns:
        ``(N, M)`` costs, m.

    Raises:
        InputError: shapes do not match, or the matrix would be too large.
    """
    A = np.asarray(a, dtype=float)
    B = np.asarray(b, dtype=float)
    if A.ndim != 3 or B.ndim != 3 or A.shape[1:] != B.shape[1:] or A.shape[2] != 3:
        raise InputError(f"frames must be (N, J, 3) and (M, J, 3), got {A.shape}, {B.shape}")
    if A.shape[0] * B.shape[0] > MAX_DTW_CELLS:
        raise InputError(f"motions of {A.shape[0]} and {B.shape[0]} frames are too long to "
                         "align at once; cut them into repetitions or downsample")
    out = np.empty((A.shape[0], B.shape[0]))
    # blocks bound the (n, M, J, 3) temporary to about 1e6 × 3 floats
    block = max(1, 1_000_000 // max(1, B.shape[0] * A.shape[1]))
    for i in range(0, A.shape[0], block):
        d = np.linalg.norm(A[i:i + block, None] - B[None], axis=-1)
        ok = np.isfinite(d)
        n = ok.sum(-1)
        s = np.where(ok, d, 0.0).sum(-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[i:i + block] = np.where(n > 0, s / np.maximum(n, 1), np.inf)
    return out


@dataclass(frozen=True)
class DtwResult:
    """Optimal alignment.

    Attributes:
        path: ``(K, 2)`` index pairs ``(i, j)``, monotone, from (0, 0) to (N−1, M−1).
        total_cost: Sum of the cost along the path.
        normalized_cost: ``total_cost / K`` (mean cost per aligned pair).
    """

    path: NDArray[np.int64]
    total_cost: float
    normalized_cost: float


@numba.njit(cache=True)
def _dtw_kernel(cost: np.ndarray, w: int) -> np.ndarray:  # pragma: no cover - numba
    n, m = cost.shape
    D = np.full((n + 1, m + 1), np.inf)
    D[0, 0] = 0.0
    r = (m - 1) / (n - 1) if n > 1 else 0.0
    for i in range(1, n + 1):
        c = (i - 1) * r
        lo = max(1, int(np.floor(c - w)) + 1)
        hi = min(m, int(np.ceil(c + w)) + 1)
        for j in range(lo, hi + 1):
            best = D[i - 1, j - 1]
            if D[i - 1, j] < best:
                best = D[i - 1, j]
            if D[i, j - 1] < best:
                best = D[i, j - 1]
            D[i, j] = cost[i - 1, j - 1] + best
    return D


def dtw(cost: ArrayLike, band: float = 0.2) -> DtwResult:
    """Dynamic time warping on a cost matrix with a Sakoe–Chiba band.

    Steps (1, 0), (0, 1), (1, 1) with equal weight. The band follows the diagonal from
    (0, 0) to (N−1, M−1), so series of different lengths are fine.

    Args:
        cost: ``(N, M)`` non-negative pairwise costs (``inf`` = forbidden).
        band: Band half-width: frames if ≥ 1, else a fraction of ``max(N, M)``. It is
            widened to at least the slope of the diagonal so a path always exists.

    Returns:
        The optimal path and its total and per-pair cost (:class:`DtwResult`).

    Raises:
        InputError: empty or negative cost matrix, or no finite path.
    """
    C = np.ascontiguousarray(np.asarray(cost, dtype=float))
    if C.ndim != 2 or C.size == 0:
        raise InputError("DTW needs a non-empty (N, M) cost matrix")
    if np.any(C < 0) or np.isnan(C).any():
        raise InputError("DTW costs must be non-negative numbers")
    n, m = C.shape
    if n * m > MAX_DTW_CELLS:
        raise InputError(f"a {n}×{m} DTW problem is too large; cut the motions into "
                         "repetitions or downsample them")
    w = band if band >= 1 else band * max(n, m)
    slope = max((m - 1) / (n - 1) if n > 1 else m, (n - 1) / (m - 1) if m > 1 else n)
    w = int(np.ceil(max(w, slope, 1.0)))
    D = _dtw_kernel(C, w)
    if not np.isfinite(D[n, m]):
        raise InputError("no finite DTW path: the motions share no comparable frames "
                         "within the band")
    # backtrack
    i, j = n, m
    path = [(n - 1, m - 1)]
    while (i, j) != (1, 1):
        moves = ((D[i - 1, j - 1], i - 1, j - 1), (D[i - 1, j], i - 1, j),
                 (D[i, j - 1], i, j - 1))
        _, i, j = min(moves, key=lambda x: x[0])
        path.append((i - 1, j - 1))
    p = np.array(path[::-1], dtype=np.int64)
    return DtwResult(p, float(D[n, m]), float(D[n, m]) / len(p))


@dataclass(frozen=True)
class ComparisonResult:
    """Joint-by-joint comparison of two motions.

    Attributes:
        joints: Compared joint (or role) names.
        path: ``(K, 2)`` aligned frame index pairs (a, b).
        times_a, times_b: ``(K,)`` times of the aligned frames.
        distances: ``(K, J)`` per-joint distance (m) along the alignment (NaN = missing).
        mean_distance_m: Mean of ``distances`` over all finite entries.
        per_joint_mean_m: ``(J,)`` mean distance of each joint.
        similarity: ``100·exp(−mean_distance_m / scale_m)`` (module docstring).
        scale_m: Distance scale of the score.
    """

    joints: list[str]
    path: NDArray[np.int64]
    times_a: FloatArray
    times_b: FloatArray
    distances: FloatArray
    mean_distance_m: float
    per_joint_mean_m: FloatArray
    similarity: float
    scale_m: float

    def __repr__(self) -> str:
        # A notebook shows the result: its figures, not the (K, J) arrays.
        return (f"ComparisonResult({len(self.joints)} joints, {len(self.path)} aligned "
                f"frame pairs, mean distance {100 * self.mean_distance_m:.2f} cm, "
                f"similarity {self.similarity:.1f} (scale {self.scale_m:g} m))")

    def per_joint(self) -> dict[str, float]:
        """``{joint: mean distance (m)}`` — :attr:`per_joint_mean_m` by name.

        Returns:
            Joint (or role) name -> mean distance, m.
        """
        return {j: float(d) for j, d in zip(self.joints, self.per_joint_mean_m, strict=True)}

    @property
    def distance_over_time(self) -> FloatArray:
        """``(K,)`` mean joint distance of each aligned pair (the UI's difference plot)."""
        with np.errstate(invalid="ignore"):
            return np.nanmean(self.distances, axis=1)


def similarity_score(mean_distance_m: float, scale_m: float = 0.10) -> float:
    """``100·exp(−d/scale)``: 100 identical, 61 at 5 cm, 37 at 10 cm (module docstring).

    Args:
        mean_distance_m: Mean joint distance, m.
        scale_m: Distance at which the score is 100/e, m.

    Returns:
        The score, 0–100.

    Raises:
        InputError: ``scale_m`` not positive.
    """
    if scale_m <= 0:
        raise InputError("scale_m must be > 0")
    return float(100.0 * np.exp(-mean_distance_m / scale_m))


def _result(names: list[str], path: NDArray[np.int64], ta: FloatArray, tb: FloatArray,
            A: FloatArray, B: FloatArray, scale_m: float) -> ComparisonResult:
    d = np.linalg.norm(A[path[:, 0]] - B[path[:, 1]], axis=-1)
    if not np.isfinite(d).any():
        raise InsufficientDataError("no joint is present in both motions at the same time")
    mean = float(np.nanmean(d))
    with np.errstate(invalid="ignore"):
        per = np.nanmean(np.where(np.isfinite(d), d, np.nan), axis=0)
    return ComparisonResult(names, path, ta[path[:, 0]], tb[path[:, 1]], d, mean, per,
                            similarity_score(mean, scale_m), scale_m)


def compare_motions(a: SkeletonSeries, b: SkeletonSeries, *, by_role: bool = False,
                    align: bool = True, band: float = 0.2, scale_m: float = 0.10
                    ) -> ComparisonResult:
    """Compare two motions (same frame, e.g. both KSCC-calibrated), time-aligned by DTW.

    Args:
        a, b: The two users' skeleton series.
        by_role: Compare different joint sets through their shared roles.
        align: DTW-align (motions at different speeds); otherwise frames are paired by
            index and the series must have equal length.
        band: Sakoe–Chiba band for :func:`dtw`.
        scale_m: Distance scale of the similarity score.

    Returns:
        The per-joint distances (m) along the alignment, their means and the similarity
        score (:class:`ComparisonResult`).

    Raises:
        InputError: mismatched joint sets (without ``by_role``), unequal lengths
            without alignment.
        InsufficientDataError: an empty series or no joint present in both.
    """
    names, ia, ib = common_joints(a.joint_set, b.joint_set, by_role)
    if len(a) == 0 or len(b) == 0:
        raise InsufficientDataError("both motions need at least one frame")
    A = _usable(a)[:, ia]
    B = _usable(b)[:, ib]
    for P in (A, B):
        check_metres(P[len(P) // 2])
    if align:
        path = dtw(frame_costs(A, B), band).path
    else:
        if len(a) != len(b):
            raise InputError(f"without time alignment the motions must have equal length "
                             f"({len(a)} vs {len(b)} frames); use align=True")
        k = np.arange(len(a), dtype=np.int64)
        path = np.stack([k, k], 1)
    return _result(names, path, a.times, b.times, A, B, scale_m)


def joint_distances(a: SkeletonSeries, b: SkeletonSeries, *, by_role: bool = False,
                    max_gap_s: float = 0.05) -> tuple[FloatArray, list[str], FloatArray]:
    """Per-joint distances over time of two simultaneous streams (live side by side).

    Each frame of ``a`` is paired with the frame of ``b`` nearest in time; pairs further
    apart than ``max_gap_s`` get NaN.

    Args:
        a: First stream (its times are kept).
        b: Second stream, same frame and clock.
        by_role: Map joints by role (different joint sets).
        max_gap_s: Largest time difference of a frame pair, s.

    Returns:
        ``(times, joints, distances)`` with ``times`` of ``a`` (T,), the compared joint
        names and ``(T, J)`` distances in metres.

    Raises:
        InsufficientDataError: a stream has no frames.
        InputError: joint sets that cannot be compared.
    """
    names, ia, ib = common_joints(a.joint_set, b.joint_set, by_role)
    if len(b) == 0:
        raise InsufficientDataError("the second stream has no frames")
    A = _usable(a)[:, ia]
    B = _usable(b)[:, ib]
    # nearest frame of b for each frame of a
    hi = np.clip(np.searchsorted(b.times, a.times), 0, len(b) - 1)
    lo = np.clip(hi - 1, 0, len(b) - 1)
    k = np.where(np.abs(b.times[lo] - a.times) <= np.abs(b.times[hi] - a.times), lo, hi)
    d = np.linalg.norm(A - B[k], axis=-1)
    d[np.abs(b.times[k] - a.times) > max_gap_s] = np.nan
    return a.times.copy(), names, d


__all__ = [
    "MAX_DTW_CELLS", "ComparisonResult", "DtwResult", "common_joints", "compare_motions", "dtw",
    "frame_costs", "joint_distances", "similarity_score",
]
