"""Active areas on the floor of the 3D view: where each sensor sees a whole standing body.

The polygon comes from :func:`engine.coverage.active_area_polygon` (the frustum/body
cylinder test, the trapezoid of seed 004 for a level sensor) from the sensor's pose
(height, tilt), its depth field of view and the range of its preset (Kinect v1 / v2 /
Azure Kinect, :func:`model_key`), and is drawn as a closed outline a few millimetres above
the floor in the sensor's colour, under ``/active_area/<id>``.

:class:`ActiveAreaLayer` keeps the outlines current from server start: it draws every
node with a known pose at once, redraws when a node connects, goes or changes its pose,
and adds an "Active areas" checkbox to the 3D view's GUI to hide or show them.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from app.viewer.scene import sensor_color
from engine.coverage import SENSOR_MODELS, SensorSpec, active_area_polygon
from engine.errors import InputError

if TYPE_CHECKING:  # viser is needed only with the 3D view on (the Viewer loads it)
    import viser

log = logging.getLogger("gaitrig.viewer")


@dataclass(frozen=True)
class ActiveArea:
    """One sensor's active area: id and world floor polygon ``(K, 3)`` (z = 0)."""

    id: str
    polygon: NDArray[np.float64]


def populate_active_areas(server: viser.ViserServer, areas: Sequence[ActiveArea],
                          visible: bool = True) -> None:
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
                                       np.broadcast_to(color, segs.shape).copy(), thickness=0.03,
                                       visible=visible)
        c = P.mean(axis=0)
        server.scene.add_label(f"/active_area/{a.id}/label", f"{a.id} active area",
                               position=(float(c[0]), float(c[1]), 0.02), visible=visible)


def model_key(model: str) -> str:
    """``engine.coverage.SENSOR_MODELS`` preset of a node's reported sensor model."""
    m = model.lower()
    if "v1" in m or "360" in m:
        return "kinect_v1"
    if "azure" in m or "k4a" in m:
        return "azure_nfov"
    return "kinect_v2"


def pose_numbers(T: NDArray[np.float64]) -> tuple[float, float]:
    """Height above the floor (m) and downward tilt (deg) of a ``T_world_sensor``."""
    axis = T[:3, 2]  # optical axis (+Z of the camera) in the world
    tilt = float(np.degrees(np.arcsin(np.clip(-axis[2], -1.0, 1.0))))
    return float(T[2, 3]), tilt


def node_area(node: Any) -> ActiveArea | str:
    """A node's active area, or why it has none (one sentence saying what to fix).

    Args:
        node: A registry node session (``id``, ``sensor.model``, ``sensor.fov_deg``,
            ``sensor.T_world_sensor``).
    """
    if node.sensor.T_world_sensor is None:
        return "pose unknown: calibrate the rig to get its height and area"
    T = np.asarray(node.sensor.T_world_sensor, dtype=float)
    h, _ = pose_numbers(T)
    if h <= 0:
        return f"sensor height {h:.2f} m is not above the floor; check the pose"
    m = SENSOR_MODELS[model_key(node.sensor.model)]
    hfov, vfov = node.sensor.fov_deg
    try:
        poly = active_area_polygon(SensorSpec(node.id, T, float(hfov), float(vfov),
                                              m.min_range_m, m.max_range_m))
    except InputError as e:
        return str(e)
    return ActiveArea(node.id, np.asarray(poly, dtype=float))


def node_areas(nodes: Sequence[Any]) -> list[ActiveArea]:
    """The active areas of the nodes that have one, in id order."""
    out = []
    for n in sorted(nodes, key=lambda n: n.id):
        a = node_area(n)
        if isinstance(a, ActiveArea):
            out.append(a)
    return out


class ActiveAreaLayer:
    """Every node's active area in the 3D view, from server start, toggleable.

    Args:
        server: The viser server.
        hub: The node hub (its registry's nodes and listeners are used).
    """

    def __init__(self, server: viser.ViserServer, hub: Any) -> None:
        self.server = server
        self.hub = hub
        self.toggle = server.gui.add_checkbox(
            "Active areas", initial_value=True,
            hint="floor area where each sensor sees a whole standing body (seed 004)")
        self.toggle.on_update(lambda _ev: self.redraw())
        hub.registry.listeners.append(self._on_nodes)
        self.redraw()

    @property
    def visible(self) -> bool:
        return bool(self.toggle.value)

    def redraw(self) -> None:
        """Draw the current nodes' areas (hidden, not removed, when toggled off)."""
        populate_active_areas(self.server, node_areas(list(self.hub.registry.nodes.values())),
                              self.visible)

    def _on_nodes(self, _node: Any) -> None:
        try:
            self.redraw()
        except Exception:  # the 3D view must never take the node link down
            log.exception("could not draw the active areas")
