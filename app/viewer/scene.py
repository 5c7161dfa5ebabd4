"""The viser 3D view that runs inside the server process (its own port).

One ``populate_*`` function per panel, each idempotent (re-calling it replaces the
panel's scene nodes), so later panels (point clouds, skeletons, coverage, calibration
graph) are added the same way::

    def populate_clouds(server: viser.ViserServer, clouds: ...) -> None:
        server.scene.add_point_cloud("/clouds/S1", ...)

and called from the lifespan or from a hub listener (``hub.registry.listeners`` fires on
node connect/disconnect, ``hub.skeleton_listeners`` on every skeleton frame).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import viser
from numpy.typing import NDArray

from engine.geometry import quat_from_matrix

log = logging.getLogger("gaitrig.viewer")


@dataclass(frozen=True)
class SensorView:
    """What the 3D view shows of one sensor.

    Attributes:
        id: sensor id.
        T_world_sensor: 4×4 pose (OpenCV camera frame: +Z forward, +Y down).
        fov_deg: (horizontal, vertical) depth field of view in degrees.
        connected: whether its node is online (drawn grey when not).
    """

    id: str
    T_world_sensor: NDArray[np.float64]
    fov_deg: tuple[float, float] = (70.6, 60.0)
    connected: bool = True


def populate_floor(server: viser.ViserServer, size_m: float = 12.0, cell_m: float = 0.5) -> None:
    """Floor grid in the world XY plane at the origin (marker 1), with the world axes."""
    server.scene.add_grid("/floor/grid", width=size_m, height=size_m, plane="xy",
                          cell_size=cell_m, section_size=1.0)
    server.scene.add_frame("/floor/origin", axes_length=0.4, axes_radius=0.012)


def populate_sensors(server: viser.ViserServer, sensors: Sequence[SensorView]) -> None:
    """Each sensor as a frustum (depth field of view) with its axes and a label."""
    server.scene.remove_by_name("/sensors")  # sensors may have gone: redraw from scratch
    for s in sensors:
        T = np.asarray(s.T_world_sensor, dtype=float)
        wxyz = np.asarray(quat_from_matrix(T[:3, :3]), dtype=float)
        pos = np.asarray(T[:3, 3], dtype=float)
        name = f"/sensors/{s.id}"
        color = (30, 120, 220) if s.connected else (150, 150, 150)
        server.scene.add_frame(name, wxyz=wxyz, position=pos, axes_length=0.25,
                               axes_radius=0.01)
        hfov, vfov = (math.radians(a) for a in s.fov_deg)
        aspect = math.tan(hfov / 2) / math.tan(vfov / 2)
        server.scene.add_camera_frustum(f"{name}/frustum", fov=vfov, aspect=aspect, scale=0.35,
                                        color=color)
        server.scene.add_label(f"{name}/label", s.id + ("" if s.connected else " (offline)"),
                               position=(0.0, -0.15, 0.0))


class Viewer:
    """The viser server owned by the FastAPI lifespan.

    Args:
        host: interface to listen on.
        port: port (0 picks a free one; the chosen port is in :attr:`port`).
    """

    def __init__(self, host: str, port: int) -> None:
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.port = int(self.server.get_port())
        populate_floor(self.server)
        log.info("3D view on port %d", self.port)

    def stop(self) -> None:
        """Shut the viser server down."""
        self.server.stop()
