"""The bipartite sensor/marker graph: per-observation Procrustes, connectivity, chaining.

Nodes are sensors and markers; an edge joins a sensor to a marker it observed (an accepted
:class:`~engine.calibration.corners3d.Observation`), carrying ``T_sensor_marker`` from a
rigid Procrustes fit of the marker's model corners to the observed 3D corners. Marker
``origin`` (1) defines the world. The seed paper (000) chains transforms along shortest
paths from the origin marker; we weight each edge by its expected corner error (from the
corner covariances, which grow with distance and viewing obliqueness) so the chain takes
the most trustworthy path, not the fewest hops.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from engine.calibration.corners3d import Observation
from engine.calibration.markers import marker_model_corners
from engine.errors import CalibrationError
from engine.geometry import invert_transform, procrustes, transform_points
from engine.wording import named

FloatArray = NDArray[np.float64]


@dataclass
class Edge:
    """One sensor↔marker observation used by the calibration.

    Attributes:
        sensor_id: Sensor id.
        marker_id: Marker id.
        T_sensor_marker: Procrustes pose of the marker in the sensor frame.
        residual_m: RMS corner residual of that fit (m).
        sigma_m: Expected corner error from the covariances (m), the chaining weight.
        obs: The observation.
    """

    sensor_id: str
    marker_id: int
    T_sensor_marker: FloatArray
    residual_m: float
    sigma_m: float
    obs: Observation


#: Largest RMS misfit (m) of an observation's four 3D corners to the marker's square (or
#: 4 × the corners' expected error, if larger): more means the corners are not the printed
#: square (partly occluded, folded, a person standing on it) and the observation is
#: rejected with that reason.
MAX_SQUARE_RMS_M = 0.01
#: Largest relative difference between the measured and the given edge length.
MAX_SIZE_MISMATCH = 0.15


def build_edges(observations: Sequence[Observation], marker_sizes: Mapping[int, float]
                ) -> list[Edge]:
    """Procrustes per accepted observation (markers of unknown size are skipped).

    An observation whose corners do not fit the marker's square is marked rejected (in
    place, with the reason): a measured edge length far from the given one says the size
    is wrong, a large misfit says the marker is partly occluded or not flat.

    Args:
        observations: Every sensor↔marker observation.
        marker_sizes: Marker id -> edge length, m.

    Returns:
        One edge (``T_sensor_marker`` and its expected error) per usable observation.
    """
    edges: list[Edge] = []
    for o in observations:
        if not o.accepted or o.marker_id not in marker_sizes:
            continue
        size = marker_sizes[o.marker_id]
        model = marker_model_corners(size)
        T = procrustes(model, o.corners)
        res = transform_points(T, model) - o.corners
        rms = float(np.sqrt(np.mean(np.sum(res * res, axis=1))))
        measured = float(np.mean(np.linalg.norm(o.corners - np.roll(o.corners, -1, axis=0),
                                                axis=1)))
        o.measured_edge_m, o.given_edge_m = measured, size
        if abs(measured - size) > MAX_SIZE_MISMATCH * size:
            o.accepted = False
            o.reason = (f"marker {o.marker_id} measures {measured * 100:.1f} cm in depth but "
                        f"its edge length was given as {size * 100:.1f} cm: check the size "
                        "(the black square, without the white border)")
            continue
        sigma = float(np.sqrt(np.mean(np.trace(o.cov, axis1=1, axis2=2))))
        if rms > max(MAX_SQUARE_RMS_M, 4 * sigma):
            o.accepted = False
            o.reason = (f"the 3D corners of marker {o.marker_id} miss its square by "
                        f"{rms * 1000:.0f} mm RMS: partly occluded, not flat, or someone "
                        "stood on it during the capture")
            continue
        edges.append(Edge(o.sensor_id, o.marker_id, T, rms, sigma, o))
    return edges


def check_connectivity(sensor_ids: Sequence[str], edges: Sequence[Edge], origin: int = 1,
                       rejected: Sequence[Observation] = ()) -> None:
    """Raise :class:`CalibrationError` naming every sensor with no path to marker ``origin``.

    The message says, per unreachable sensor, what it saw and why observations were
    rejected, so the user knows which marker to move or which sensor to turn.

    Args:
        sensor_ids: The sensors to calibrate.
        edges: The usable edges.
        origin: The world's marker.
        rejected: Rejected observations (their reasons go in the message).

    Raises:
        CalibrationError: a sensor cannot be reached from ``origin``.
    """
    adj: dict[str, set[str]] = {}
    for e in edges:
        s, m = f"s:{e.sensor_id}", f"m:{e.marker_id}"
        adj.setdefault(s, set()).add(m)
        adj.setdefault(m, set()).add(s)
    start = f"m:{origin}"
    reach = {start}
    stack = [start]
    while stack:
        for nb in adj.get(stack.pop(), ()):
            if nb not in reach:
                reach.add(nb)
                stack.append(nb)
    bad = [s for s in sensor_ids if f"s:{s}" not in reach]
    if not bad:
        return
    lines = []
    if start not in adj:
        lines.append(f"marker {origin} (the world origin) is not seen by any sensor with depth")
    for s in bad:
        seen = sorted(e.marker_id for e in edges if e.sensor_id == s)
        why = [f"marker {o.marker_id}: {o.reason}" for o in rejected
               if o.sensor_id == s and not o.accepted]
        txt = f"{s} sees markers {seen}" if seen else f"{s} sees no usable marker"
        if why:
            txt += " (" + "; ".join(why) + ")"
        lines.append(txt)
    wrong = [o for o in rejected if not o.accepted and _wrong_size(o)]
    checked = [o for o in rejected if np.isfinite(o.measured_edge_m)]
    if wrong and 2 * len(wrong) >= len(checked):
        # one wrong number in the form, not a room problem: say that, not "move markers"
        measured = float(np.median([o.measured_edge_m for o in wrong]))
        given = sorted({round(o.given_edge_m * 100, 1) for o in wrong})
        raise CalibrationError(
            f"The markers measure {measured * 100:.0f} cm in the depth images "
            f"({len(wrong)} of {len(checked)} views) but {' / '.join(f'{g:g}' for g in given)}"
            " cm was entered: enter the black square's edge length (without the white "
            f"border) and capture again. Details: {named('sensor', bad, 'has', 'have')} no chain "
            f"of shared markers to marker {origin}: " + "; ".join(lines) + ".",
            unreachable=bad,
        )
    raise CalibrationError(
        f"{named('sensor', bad, 'has', 'have')} no chain of shared markers to marker {origin}: "
        + "; ".join(lines)
        + ". Place a marker where an unreachable sensor and a reachable one both see it.",
        unreachable=bad,
    )


def _wrong_size(o: Observation) -> bool:
    return bool(np.isfinite(o.measured_edge_m) and np.isfinite(o.given_edge_m)
                and abs(o.measured_edge_m - o.given_edge_m) > MAX_SIZE_MISMATCH * o.given_edge_m)


def chain_poses(sensor_ids: Sequence[str], edges: Sequence[Edge], origin: int = 1
                ) -> tuple[dict[str, FloatArray], dict[int, FloatArray], list[tuple[str, int]]]:
    """Shortest-path chaining from the origin marker (the paper's estimate).

    Edge weight = the observation's expected corner error squared (variances add along a
    chain). Each node's pose is composed along its shortest path.

    Args:
        sensor_ids: The sensors.
        edges: The usable edges.
        origin: The world's marker (its pose is the identity).

    Returns:
        ``(T_world_sensor, T_world_marker, chain edges as (sensor, marker))``.

    Raises:
        CalibrationError: some sensor has no path (see :func:`check_connectivity`).
    """
    check_connectivity(sensor_ids, edges, origin)
    markers = sorted({e.marker_id for e in edges})
    nodes = [f"m:{m}" for m in markers] + [f"s:{s}" for s in sensor_ids]
    index = {n: i for i, n in enumerate(nodes)}
    rows, cols, w = [], [], []
    by_pair: dict[tuple[int, int], Edge] = {}
    for e in edges:
        i, j = index[f"m:{e.marker_id}"], index[f"s:{e.sensor_id}"]
        wt = max(e.sigma_m, 1e-6) ** 2
        rows += [i, j]
        cols += [j, i]
        w += [wt, wt]
        by_pair[(i, j)] = by_pair[(j, i)] = e
    # scipy where it is used: the server's start imports this module and needs none
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import dijkstra

    g = csr_matrix((w, (rows, cols)), shape=(len(nodes), len(nodes)))
    src = index[f"m:{origin}"]
    _, pred = dijkstra(g, directed=False, indices=src, return_predecessors=True)
    T_w: dict[int, FloatArray] = {src: np.eye(4)}

    def pose(i: int) -> FloatArray:
        if i in T_w:
            return T_w[i]
        p = int(pred[i])
        Tp = pose(p)
        e = by_pair[(p, i)]
        # marker→sensor: T_w_s = T_w_m · T_m_s ; sensor→marker: T_w_m = T_w_s · T_s_m
        T_w[i] = (Tp @ invert_transform(e.T_sensor_marker) if nodes[i].startswith("s:")
                  else Tp @ e.T_sensor_marker)
        return T_w[i]

    T_ws = {s: pose(index[f"s:{s}"]) for s in sensor_ids}
    T_wm = {m: pose(index[f"m:{m}"]) for m in markers if pred[index[f"m:{m}"]] >= 0
            or index[f"m:{m}"] == src}
    used = []
    for i in range(len(nodes)):
        p = int(pred[i])
        if p >= 0:
            e = by_pair[(p, i)]
            used.append((e.sensor_id, e.marker_id))
    return T_ws, T_wm, used
