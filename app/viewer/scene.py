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
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from engine.geometry import quat_from_matrix
from engine.skeleton import KINECT_V2, TrackingState

if TYPE_CHECKING:  # viser is needed only with the 3D view on (the Viewer loads it)
    import viser

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


def populate_floor(server: viser.ViserServer, size_m: float = 24.0, cell_m: float = 0.5) -> None:
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
        color = sensor_color(s.id) if s.connected else (150, 150, 150)
        server.scene.add_frame(name, wxyz=wxyz, position=pos, axes_length=0.25,
                               axes_radius=0.01)
        hfov, vfov = (math.radians(a) for a in s.fov_deg)
        aspect = math.tan(hfov / 2) / math.tan(vfov / 2)
        server.scene.add_camera_frustum(f"{name}/frustum", fov=vfov, aspect=aspect, scale=0.35,
                                        color=color)
        server.scene.add_label(f"{name}/label", s.id + ("" if s.connected else " (offline)"),
                               position=(0.0, -0.15, 0.0))


_SENSOR_COLORS = [(230, 80, 60), (40, 160, 90), (50, 110, 220), (220, 160, 30),
                  (160, 70, 200), (30, 170, 190)]


def sensor_color(node_id: str) -> tuple[int, int, int]:
    """A stable colour per sensor id."""
    return _SENSOR_COLORS[sum(ord(c) for c in node_id) % len(_SENSOR_COLORS)]


def populate_skeleton(server: viser.ViserServer, node_id: str, positions: NDArray[np.floating],
                      states: NDArray[np.integer]) -> None:
    """The live skeleton(s) one sensor reports, drawn in that sensor's frame.

    The panel hangs below ``/sensors/<id>`` so it follows the pose shown for the sensor
    (true pose now, the calibration's later). Bones between two tracked joints are drawn
    in the sensor's colour, bones touching an inferred joint in grey; joints without an
    estimate are left out.

    Args:
        server: the viser server.
        node_id: sensor id.
        positions: ``(B, J, 3)`` metres, sensor frame (NaN = no estimate).
        states: ``(B, J)`` tracking states.
    """
    name = f"/sensors/{node_id}/skeleton"
    pos = np.asarray(positions, dtype=float)
    st = np.asarray(states)
    ok = np.isfinite(pos).all(axis=-1) & (st > TrackingState.NOT_TRACKED)
    if pos.shape[0] == 0 or not ok.any():
        server.scene.remove_by_name(name)
        return
    segs, cols = [], []
    color = np.array(sensor_color(node_id), dtype=np.uint8)
    grey = np.array((150, 150, 150), dtype=np.uint8)
    if pos.shape[1] == len(KINECT_V2.joints):
        par = KINECT_V2.parent_indices
        for b in range(pos.shape[0]):
            for j, p in enumerate(par):
                if p >= 0 and ok[b, j] and ok[b, p]:
                    segs.append((pos[b, p], pos[b, j]))
                    both = st[b, j] == st[b, p] == TrackingState.TRACKED
                    cols.append((color, color) if both else (grey, grey))
    if segs:
        server.scene.add_line_segments(name, np.asarray(segs, dtype=np.float32),
                                       np.asarray(cols, dtype=np.uint8), thickness=0.015)
    else:
        # float32: viser's float16 default rounds by centimetres a few metres out
        server.scene.add_point_cloud(name, pos[ok].astype(np.float32), color, point_size=0.03,
                                     precision="float32")


class Viewer:
    """The viser server owned by the FastAPI lifespan.

    Args:
        host: interface to listen on.
        port: port (0 picks a free one; the chosen port is in :attr:`port`).
    """

    def __init__(self, host: str, port: int) -> None:
        import viser  # here: a server without the 3D view never loads it

        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.port = int(self.server.get_port())
        # Start behind and above the origin, looking down the walkway (+X), Z up.
        self.server.initial_camera.position = (-3.0, -4.5, 3.5)
        self.server.initial_camera.look_at = (3.5, 0.0, 0.8)
        self.server.initial_camera.up = (0.0, 0.0, 1.0)
        populate_floor(self.server)
        log.info("3D view on port %d", self.port)

    def stop(self) -> None:
        """Shut the viser server down."""
        self.server.stop()
