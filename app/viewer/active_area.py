"""Active areas on the floor of the 3D view: where each sensor sees a whole standing body.

The polygon comes from :func:`engine.coverage.active_area_polygon` (the frustum/body
cylinder test, the trapezoid of seed 004 for a level sensor) and is drawn as a closed
outline a few millimetres above the floor in the sensor's colour, under
``/active_area/<id>``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import viser
from numpy.typing import NDArray

from app.viewer.scene import sensor_color


@dataclass(frozen=True)
class ActiveArea:
    """One sensor's active area: id and world floor polygon ``(K, 3)`` (z = 0)."""

    id: str
    polygon: NDArray[np.float64]


def populate_active_areas(server: viser.ViserServer, areas: Sequence[ActiveArea]) -> None:
    """Redraw every sensor's active-area outline (sensors may have gone: from scratch)."""
    server.scene.remove_by_name("/active_area")
    for a in areas:
        P = np.asarray(a.polygon, dtype=np.float32)
        if len(P) < 3:
            continue
        P = P.copy()
        P[:, 2] = 0.005  # just above the floor grid
        segs = np.stack([P, np.roll(P, -1, axis=0)], axis=1)
        color = np.array(sensor_color(a.id), dtype=np.uint8)
        server.scene.add_line_segments(f"/active_area/{a.id}", segs,
                                       np.broadcast_to(color, segs.shape).copy(), thickness=0.03)
        c = P.mean(axis=0)
        server.scene.add_label(f"/active_area/{a.id}/label", f"{a.id} active area",
                               position=(float(c[0]), float(c[1]), 0.02))
