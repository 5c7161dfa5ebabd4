"""Live 3D view panels and the services behind the Live and Calibrate pages.

Panels (one ``populate_*`` function each, idempotent: re-calling replaces its nodes):

* :func:`populate_layout` — floor markers with their ids and the walkway outline;
* :func:`populate_graph` — the sensor/marker graph edges (which sensor sees which
  marker), labelled with where the poses come from;
* :func:`populate_cloud` — one node's share of the merged coloured point cloud;
* :func:`populate_fused_skeleton` — the fused live skeleton;
* :func:`populate_coverage` — the floor coverage heat map of the planned rig;
* :func:`populate_planning_handles` — a transform control per sensor; dragging one moves
  the planned sensor and redraws the coverage map.

Live fusion is deliberately simpler than the offline integration
(:mod:`engine.integration`, which resamples whole recordings): per joint, the mean of the
world positions from every sensor that tracks it (inferred joints count a fifth),
restricted to bodies whose spine base lies within 0.6 m of the median over sensors so a
second person does not pull the fused body.

:class:`LiveServices` owns the depth streams (:mod:`app.server.streaming`), the planner
(:mod:`app.viewer.planning`) and the viser panels; the ``live`` router starts it in the
server's lifespan.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import re
import time
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from app.server.hub import Hub
from app.server.registry import NodeSession
from app.server.streaming import HIGHLIGHT_RGB, DepthFrame, LiveStreams
from app.viewer.cloud import (
    DepthView,
    calibrated_depth_lens,
    merge_depth_views,
    scale_intrinsics,
)
from app.viewer.planning import Planner, sensors_from_nodes
from app.viewer.scene import sensor_color
from engine.geometry import quat_from_matrix
from engine.sim.rig import Rig, default_avenue_rig, marker_visibility
from engine.skeleton import KINECT_V2, TrackingState

if TYPE_CHECKING:  # viser is needed only with the 3D view on (the Viewer loads it)
    import viser

log = logging.getLogger("gaitrig.viewer.live")

CLOUD_VOXEL_M = 0.04
CLOUD_HZ = 2.0
FUSED_RGB = (20, 20, 20)


def _wxyz(T: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.asarray(quat_from_matrix(np.asarray(T, float)[:3, :3]), float)


def populate_layout(server: viser.ViserServer, layout: Rig, label: str) -> None:
    """Floor markers (squares with ids) and the walkway outline of the lab layout."""
    server.scene.remove_by_name("/layout")
    for m in layout.markers:
        T = np.asarray(m.T_world_marker, float)
        h = m.size_m / 2
        square = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]])
        corners = square @ T[:3, :3].T + T[:3, 3]
        corners[:, 2] += 0.003  # just above the grid
        segs = np.stack([corners, np.roll(corners, -1, axis=0)], axis=1).astype(np.float32)
        server.scene.add_line_segments(f"/layout/markers/{m.id}", segs, (20, 20, 20),
                                       thickness=0.015)
        server.scene.add_label(f"/layout/markers/{m.id}/label", f"marker {m.id}",
                               position=corners.mean(axis=0))
    w = layout.walkway
    a, b = np.asarray(w.start, float), np.asarray(w.end, float)
    d = (b - a) / np.linalg.norm(b - a)
    n = np.array([-d[1], d[0], 0.0]) * w.width / 2
    ring = np.array([a + n, b + n, b - n, a - n])
    ring[:, 2] = 0.004
    segs = np.stack([ring, np.roll(ring, -1, axis=0)], axis=1).astype(np.float32)
    server.scene.add_line_segments("/layout/walkway", segs, (240, 140, 0), thickness=0.03)
    server.scene.add_label("/layout/walkway/label", f"walkway ({label})",
                           position=a + 0.3 * (b - a) + n * 1.2)


def populate_graph(server: viser.ViserServer, layout: Rig,
                   sensor_poses: dict[str, NDArray[np.float64]], source: str) -> None:
    """Sensor↔marker graph: an edge where a sensor sees a floor marker.

    Args:
        server: the viser server.
        layout: markers (and sensors, for the visibility test).
        sensor_poses: pose per sensor id to draw the edges from.
        source: where the poses come from, written on the graph (e.g. "true poses of the
            simulated rig — not calibrated").
    """
    server.scene.remove_by_name("/graph")
    rig = layout
    if sensor_poses:
        import dataclasses

        from engine.sim.rig import SimSensor

        by_id = {s.id: s for s in layout.sensors}
        rig = dataclasses.replace(layout, sensors=[
            dataclasses.replace(by_id[i], T_world_sensor=T) if i in by_id
            else SimSensor(id=i, T_world_sensor=T) for i, T in sensor_poses.items()])
    vis = marker_visibility(rig)
    segs, cols = [], []
    for s in rig.sensors:
        p = np.asarray(s.T_world_sensor, float)[:3, 3]
        c = sensor_color(s.id)
        for mid, seen_by in vis.items():
            if s.id in seen_by:
                q = np.asarray(rig.marker(mid).T_world_marker, float)[:3, 3]
                segs.append((p, q))
                cols.append((c, c))
    if segs:
        server.scene.add_line_segments("/graph/edges", np.asarray(segs, np.float32),
                                       np.asarray(cols, np.uint8), thickness=0.008)
    server.scene.add_label("/graph/label", f"sensor–marker graph: {source}",
                           position=(0.0, 0.0, 2.6))


def populate_cloud(server: viser.ViserServer, node_id: str, points: NDArray[np.float32],
                   colors: NDArray[np.uint8], visible: bool = True) -> Any:
    """One node's voxel-merged points; returns the scene handle (None if no points).

    Sent as float32: viser's float16 default keeps only 11 significant bits (12 mm steps
    at 10 m, 0.5 m at 1 km), too coarse for a lab whose world origin is far away.
    """
    name = f"/cloud/{node_id}"
    if len(points) == 0:
        server.scene.remove_by_name(name)
        return None
    return server.scene.add_point_cloud(name, points, colors, point_size=0.025,
                                        point_shape="square", precision="float32",
                                        visible=visible)


def fuse_skeletons(skeletons: dict[str, tuple[NDArray[np.float64], NDArray[np.uint8]]]
                   ) -> NDArray[np.float64] | None:
    """Live fused skeleton from world-frame skeletons of several sensors (see module doc).

    Args:
        skeletons: sensor id → ``(positions (B, J, 3) world m, states (B, J))``.

    Returns:
        ``(J, 3)`` fused joints (NaN where no sensor tracks the joint), or None.
    """
    cands = []
    for pos, st in skeletons.values():
        for b in range(pos.shape[0]):
            if st[b, 0] > TrackingState.NOT_TRACKED and np.isfinite(pos[b, 0]).all():
                cands.append((pos[b], st[b]))
    if not cands:
        return None
    base = np.median(np.stack([c[0][0] for c in cands]), axis=0)
    num = np.zeros_like(cands[0][0])
    den = np.zeros(cands[0][0].shape[0])
    for p, st in cands:
        if np.linalg.norm(p[0] - base) > 0.6:
            continue
        w = np.where(st == TrackingState.TRACKED, 1.0,
                     np.where(st == TrackingState.INFERRED, 0.2, 0.0))
        w = np.where(np.isfinite(p).all(axis=1), w, 0.0)
        num += np.nan_to_num(p) * w[:, None]
        den += w
    with np.errstate(invalid="ignore", divide="ignore"):
        out = num / den[:, None]
    out[den == 0] = np.nan
    return out


def populate_fused_skeleton(server: viser.ViserServer, joints: NDArray[np.float64] | None) -> None:
    """The fused skeleton in world coordinates, thick and dark over the sensors' colours."""
    name = "/fused/skeleton"
    if joints is None or joints.shape[0] != len(KINECT_V2.joints):
        server.scene.remove_by_name(name)
        return
    ok: NDArray[np.bool_] = np.asarray(np.isfinite(joints).all(axis=1))
    segs = [(joints[p], joints[j]) for j, p in enumerate(KINECT_V2.parent_indices)
            if p >= 0 and ok[j] and ok[p]]
    if not segs:
        server.scene.remove_by_name(name)
        return
    server.scene.add_line_segments(name, np.asarray(segs, np.float32), FUSED_RGB, thickness=0.03)


def populate_coverage(server: viser.ViserServer, planner: Planner, visible: bool = True) -> None:
    """Coverage heat map lying on the floor (red = blind, hatch = seen from both sides)."""
    g = planner.grid
    img = planner.image(pixels_per_cell=2)
    server.scene.add_image("/coverage/map", img, render_width=g.x1 - g.x0,
                           render_height=g.y1 - g.y0, format="png",
                           # just above the floor grid
                           position=((g.x0 + g.x1) / 2, (g.y0 + g.y1) / 2, 0.002),
                           visible=visible)



def _natural_key(node_id: str) -> tuple[tuple[int, int | str], ...]:
    """Sort key that puts S2 before S10 (digit runs compare as numbers)."""
    return tuple((0, int(part)) if part.isdigit() else (1, part)
                 for part in re.findall(r"\d+|\D+", node_id))


class LiveServices:
    """Depth streams, planner and 3D panels of one running server.

    Args:
        hub: the node hub.
        viewer: the viser server, or None when the 3D view is disabled.
    """

    def __init__(self, hub: Hub, viewer: viser.ViserServer | None) -> None:
        self.hub = hub
        self.viewer = viewer
        self.streams = LiveStreams(hub)
        self.layout = default_avenue_rig(None)
        self.planner: Planner | None = None
        self._planner_key: tuple[str, ...] = ()
        self._cloud_frames: dict[str, DepthFrame] = {}
        self._cloud_seq: dict[str, int] = {}
        #: each node's depth lens for the live cloud (the active calibration's, or the
        #: one the node announced)
        self._depth_lens: dict[str, tuple[float, ...]] = {}
        self._cloud_task: asyncio.Task[None] | None = None
        self._handles: dict[str, Any] = {}
        self._dragging = False
        self._node_toggles: dict[str, Any] = {}
        self._layer_toggles: dict[str, Any] = {}
        self._last_fused = 0.0
        self.coverage_draw_ms: list[float] = []
        self.streams.frame_listeners.append(self._on_frame)
        if viewer is not None:
            self._build_gui()
            populate_layout(viewer, self.layout, "simulated lab layout")
            hub.skeleton_listeners.append(self._on_skeleton)
            hub.registry.listeners.append(self._on_nodes)

    # ------------------------------------------------------------------ lifecycle

    async def start(self) -> None:
        """Start streaming and the 3D panels (server lifespan)."""
        self.streams.start()
        if self.viewer is not None:
            self._cloud_task = asyncio.get_running_loop().create_task(self._cloud_loop())

    async def stop(self) -> None:
        if self._cloud_task is not None:
            self._cloud_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._cloud_task
        await self.streams.stop()

    # ------------------------------------------------------------------ planner

    def get_planner(self) -> Planner:
        """The planner, (re)built when the set of posed sensors changed."""
        sensors = sensors_from_nodes(list(self.hub.registry.nodes.values()))
        source = self._pose_source()
        # a new calibration (another source) restarts the plan from its poses
        key = (*(s.id for s in sensors), source)
        if self.planner is None or key != self._planner_key:
            self.planner = Planner(sensors, self.layout, source=source)
            self._planner_key = key
            self.planner.listeners.append(self._on_plan)
            self._on_plan(self.planner)
            self._draw_handles()
        return self.planner

    def _pose_source(self) -> str:
        """Where the planner's starting poses come from, in the user's words."""
        from app.server.calibration import active_poses

        nodes = self.hub.registry.nodes
        cal = active_poses(self.hub.settings.data_dir)
        ours = sorted(n for n in nodes if n in cal)
        if ours:
            version = cal[ours[0]]["calibration_version"]
            rest = sorted(set(nodes) - set(ours))
            return (f"calibration {version}" if not rest else
                    f"calibration {version} ({', '.join(ours)}); {', '.join(rest)} as "
                    "reported by the nodes (not calibrated)")
        if all(n.backend == "sim" for n in nodes.values()):
            return "true poses of the simulated rig (not calibrated)"
        return "poses reported by the nodes (not calibrated)"

    def _on_plan(self, planner: Planner) -> None:
        if self.viewer is None:
            return
        t0 = time.perf_counter()
        populate_coverage(self.viewer, planner, self._layer_visible("coverage"))
        self.coverage_draw_ms = ([*self.coverage_draw_ms, 1000 * (time.perf_counter() - t0)])[-50:]
        if not self._dragging:
            for s in planner.sensors:
                h = self._handles.get(s.id)
                if h is not None:
                    h.position = tuple(float(v) for v in s.T_world_sensor[:3, 3])
                    h.wxyz = tuple(float(v) for v in _wxyz(s.T_world_sensor))

    def _draw_handles(self) -> None:
        if self.viewer is None or self.planner is None:
            return
        self.viewer.scene.remove_by_name("/planning")
        self._handles.clear()
        visible = self._layer_visible("planning")
        for s in self.planner.sensors:
            h = self.viewer.scene.add_transform_controls(
                f"/planning/{s.id}", scale=0.45, position=tuple(s.T_world_sensor[:3, 3]),
                wxyz=tuple(_wxyz(s.T_world_sensor)), visible=visible)
            vfov, hfov = np.radians(s.vfov_deg), np.radians(s.hfov_deg)
            self.viewer.scene.add_camera_frustum(
                f"/planning/{s.id}/frustum", fov=float(vfov),
                aspect=float(np.tan(hfov / 2) / np.tan(vfov / 2)), scale=0.3,
                color=(255, 255, 255))
            self.viewer.scene.add_label(f"/planning/{s.id}/label", f"{s.id} (planned)",
                                        position=(0.0, 0.15, 0.0))

            def moved(ev: Any, sid: str = s.id) -> None:
                self.apply_drag(sid, ev.target.wxyz, ev.target.position)

            h.on_update(moved)
            self._handles[s.id] = h

    def apply_drag(self, sensor_id: str, wxyz: Any, position: Any) -> None:
        """A planning handle moved: re-pose the planned sensor (the map follows)."""
        from engine.geometry import quat_to_matrix

        T = np.eye(4)
        T[:3, :3] = quat_to_matrix(np.asarray(wxyz, float))
        T[:3, 3] = np.asarray(position, float)
        self._dragging = True  # the handle is already where the user put it
        try:
            if self.planner is not None:
                self.planner.move(sensor_id, T)
        except Exception as exc:
            log.warning("planning move of %s refused: %s", sensor_id, exc)
        finally:
            self._dragging = False

    # ------------------------------------------------------------------ GUI

    def _layer_visible(self, name: str) -> bool:
        t = self._layer_toggles.get(name)
        return bool(t.value) if t is not None else name != "planning"

    def _build_gui(self) -> None:
        assert self.viewer is not None
        gui = self.viewer.gui
        with gui.add_folder("Layers"):
            for name, label, default in (("cloud", "Point cloud", True),
                                         ("coverage", "Coverage map", True),
                                         ("graph", "Sensor–marker graph", True),
                                         ("planning", "Planning handles", False),
                                         ("fused", "Fused skeleton", True)):
                cb = gui.add_checkbox(label, initial_value=default)
                self._layer_toggles[name] = cb

                def toggled(_ev: Any, n: str = name) -> None:
                    self._apply_layer(n)

                cb.on_update(toggled)
        self._cloud_folder = gui.add_folder("Point cloud per sensor")

    def _apply_layer(self, name: str) -> None:
        if self.viewer is None:
            return
        on = self._layer_visible(name)
        if name == "coverage" and self.planner is not None:
            populate_coverage(self.viewer, self.planner, on)
        elif name == "planning":
            for h in self._handles.values():
                h.visible = on
        elif name == "graph":
            self._draw_graph()
        elif name == "fused" and not on:
            self.viewer.scene.remove_by_name("/fused")
        elif name == "cloud":
            for nid in list(self._cloud_frames):
                self._cloud_seq.pop(nid, None)  # redraw with the new visibility
            if not on:
                self.viewer.scene.remove_by_name("/cloud")

    def _node_toggle(self, node_id: str) -> bool:
        if self.viewer is None:
            return False
        t = self._node_toggles.get(node_id)
        if t is None:
            with self._cloud_folder:
                t = self.viewer.gui.add_checkbox(f"{node_id} points", initial_value=True)

            def toggled(_ev: Any, n: str = node_id) -> None:
                self._cloud_seq.pop(n, None)

            t.on_update(toggled)
            self._node_toggles[node_id] = t
            # listed S1, S2, … S10 whichever node's cloud came first
            for k, nid in enumerate(sorted(self._node_toggles, key=_natural_key)):
                self._node_toggles[nid].order = float(k)
        return bool(t.value)

    def _draw_graph(self) -> None:
        if self.viewer is None:
            return
        if not self._layer_visible("graph"):
            self.viewer.scene.remove_by_name("/graph")
            return
        from app.server.calibration import active_result
        from app.viewer.calibration import populate_calibration_graph

        cal = active_result(self.hub.settings.data_dir)
        if cal is not None:  # the active calibration: its sensors, markers, residual edges
            self.viewer.scene.remove_by_name("/graph")
            populate_calibration_graph(self.viewer, cal, root="/graph")
            return
        poses = {s.id: np.asarray(s.sensor.T_world_sensor, float)
                 for s in self.hub.registry.nodes.values() if s.sensor.T_world_sensor is not None}
        sim = all(s.backend == "sim" for s in self.hub.registry.nodes.values())
        populate_graph(self.viewer, self.layout, poses,
                       "true poses of the simulated rig (no calibration yet)" if sim
                       else "poses reported by the nodes (no calibration yet)")

    # ------------------------------------------------------------------ listeners

    def _refresh_lenses(self) -> None:
        """Each node's depth lens for the live cloud: the active calibration's camera
        model while the node reports the camera it was calibrated with, else the lens the
        node announced when it connected (``sensor_lens``: an Azure Kinect's factory
        calibration, so the view is right before any calibration). A lens either source
        has that the ray table cannot model, or none at all: pinhole."""
        from app.server.calibration import active_result

        cal = active_result(self.hub.settings.data_dir)
        cameras = {} if cal is None else cal.meta.get("cameras", {})
        lenses: dict[str, tuple[float, ...]] = {}
        for nid, s in self.hub.registry.nodes.items():
            if s.sensor.depth_K is None:
                continue
            d = calibrated_depth_lens(cameras, nid, s.sensor.depth_K, s.sensor.depth_size)
            ann = s.lens.depth if s.lens is not None else None
            # the announcement passes the calibration's checks too (same camera, a lens
            # the ray table models)
            a = (calibrated_depth_lens({nid: {"depth": ann.model_dump()}}, nid,
                                       s.sensor.depth_K, s.sensor.depth_size)
                 if ann is not None else ())
            if d is None:
                log.warning("the depth lens calibration %s recorded for %s does not fit the "
                            "camera it reports now (another K) or is not usable: its live "
                            "cloud is drawn %s until it is calibrated again",
                            getattr(cal, "version", "?"), nid,
                            "with the lens the node announced" if a else "without a lens")
            if a is None:
                log.warning("the depth lens %s announced (%s) is not one the live cloud can "
                            "draw: it is drawn %s", nid, s.lens.source if s.lens else "?",
                            "with its calibration's lens" if d else "without a lens")
            lens = d or a
            if lens:
                lenses[nid] = lens
        if lenses != self._depth_lens:
            self._cloud_seq.clear()  # redraw with the new rays
        self._depth_lens = lenses

    def _on_nodes(self, _s: NodeSession) -> None:
        try:
            self._refresh_lenses()
        except Exception:
            log.exception("could not read the depth lenses of the active calibration")
        try:
            for nid in sorted(self.hub.registry.nodes):  # per-sensor toggles in id order
                self._node_toggle(nid)
            self._draw_graph()
            self.get_planner()
        except Exception:
            log.exception("could not update the graph / planner")

    def _on_frame(self, frame: DepthFrame) -> None:
        self._cloud_frames[frame.node] = frame

    def _on_skeleton(self, s: NodeSession) -> None:
        now = time.time()
        if now - self._last_fused < 0.1 or self.viewer is None or not self._layer_visible("fused"):
            return
        if not self.viewer.get_clients():
            return  # nobody looks (as the sensors' skeletons in app.main)
        self._last_fused = now
        sk: dict[str, tuple[NDArray[np.float64], NDArray[np.uint8]]] = {}
        for n in self.hub.registry.nodes.values():
            if (not n.connected or n.skeleton is None or n.sensor.T_world_sensor is None
                    or n.skeleton.t_server is None or now - n.skeleton.t_server > 0.5):
                continue
            T = np.asarray(n.sensor.T_world_sensor, float)
            pos = n.skeleton.positions.astype(float) @ T[:3, :3].T + T[:3, 3]
            sk[n.id] = (pos, n.skeleton.states)
        try:
            populate_fused_skeleton(self.viewer, fuse_skeletons(sk))
        except Exception:
            log.exception("could not draw the fused skeleton")

    def cloud_view(self, f: DepthFrame) -> DepthView | None:
        """What the live cloud unprojects of a node's depth frame: the frame with its
        node's intrinsics at the frame's scale, pose and depth lens (None while the node
        has no intrinsics or pose)."""
        s = self.hub.registry.get(f.node)
        if s is None or s.sensor.depth_K is None or s.sensor.T_world_sensor is None:
            return None
        K = scale_intrinsics(np.asarray(s.sensor.depth_K), f.scale)
        # the lens's coefficients hold at any image scale (only K scales)
        return DepthView(f.depth_mm, K, np.asarray(s.sensor.T_world_sensor, float),
                         sensor_color(f.node), f.body, self._depth_lens.get(f.node, ()))

    async def _cloud_loop(self) -> None:
        """Redraw the clouds of nodes with a new depth frame, ≤ CLOUD_HZ per node."""
        assert self.viewer is not None
        while True:
            await asyncio.sleep(1.0 / CLOUD_HZ)
            self.streams.cloud_consumers = len(self.viewer.get_clients())
            if not self._layer_visible("cloud"):
                continue
            for nid, f in list(self._cloud_frames.items()):
                if self._cloud_seq.get(nid) == f.seq:
                    continue  # nothing new: nothing re-sent
                view = self.cloud_view(f)
                if view is None:
                    continue
                self._cloud_seq[nid] = f.seq
                visible = self._node_toggle(nid)
                try:
                    pts, cols = await asyncio.to_thread(merge_depth_views, [view], CLOUD_VOXEL_M,
                                                        (0.3, 8.0), HIGHLIGHT_RGB)
                    populate_cloud(self.viewer, nid, pts, cols, visible)
                except Exception:
                    log.exception("could not update the point cloud of %s", nid)
