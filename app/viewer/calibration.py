"""3D panel of a spatial calibration: sensors, markers and the sensor↔marker graph with
edges coloured by residual (green < 1 mm, yellow 1–3 mm, red > 3 mm)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from engine.calibration.pipeline import CalibrationResult
from engine.geometry import quat_from_matrix

if TYPE_CHECKING:  # viser is needed only with the 3D view on (the Viewer loads it)
    import viser

GOOD_M = 0.001
FAIR_M = 0.003


def residual_colour(residual_m: float) -> tuple[int, int, int]:
    """RGB of an edge by its residual (grey when unknown)."""
    if not math.isfinite(residual_m):
        return (150, 150, 150)
    if residual_m < GOOD_M:
        return (40, 160, 70)
    if residual_m < FAIR_M:
        return (220, 170, 20)
    return (210, 50, 40)


def populate_calibration_graph(server: viser.ViserServer, result: CalibrationResult,
                               root: str = "/calibration") -> None:
    """Draw the calibration: a camera frustum-like frame per sensor, a square per marker
    (marker 1 with world axes), one line per observation coloured by its residual."""
    server.scene.add_frame(root, axes_length=0.4, axes_radius=0.01)
    version = f"version {result.version}" if result.version is not None else "unsaved"
    server.scene.add_label(f"{root}/label", f"calibration {version}: sensor–marker edges "
                           "coloured by residual", position=(0.0, 0.0, 2.6))
    for sid, T in result.T_world_sensor.items():
        q = quat_from_matrix(T[:3, :3])
        server.scene.add_frame(f"{root}/sensors/{sid}", wxyz=np.asarray(q, dtype=float),
                               position=np.asarray(T[:3, 3], dtype=float), axes_length=0.25,
                               axes_radius=0.008)
        r = result.sensor_residual_m.get(sid, float("nan"))
        txt = f"{sid} · {r * 1000:.1f} mm" if math.isfinite(r) else sid
        server.scene.add_label(f"{root}/sensors/{sid}/label", txt, position=(0.0, 0.0, 0.0))
    for mid, T in result.T_world_marker.items():
        h = result.marker_sizes.get(mid, 0.2) / 2
        corners = np.array([[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]], dtype=float)
        w = corners @ T[:3, :3].T + T[:3, 3]
        segs: NDArray[np.float32] = np.stack([w, np.roll(w, -1, axis=0)], axis=1).astype(
            np.float32)
        server.scene.add_line_segments(f"{root}/markers/{mid}", segs,
                                       colors=(20, 20, 20), thickness=3.0,
                                       thickness_units="screen")
        server.scene.add_label(f"{root}/markers/{mid}/label", f"marker {mid}",
                               position=np.asarray(T[:3, 3], dtype=float))
    for e in result.edges:
        if e.sensor_id not in result.T_world_sensor or e.marker_id not in result.T_world_marker:
            continue
        a = result.T_world_sensor[e.sensor_id][:3, 3]
        b = result.T_world_marker[e.marker_id][:3, 3]
        seg = np.array([[a, b]], dtype=np.float32)
        server.scene.add_line_segments(f"{root}/edges/{e.sensor_id}-{e.marker_id}", seg,
                                       colors=residual_colour(e.residual_m),
                                       thickness=4.0 if e.in_chain else 2.0,
                                       thickness_units="screen")
