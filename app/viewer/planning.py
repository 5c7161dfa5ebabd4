"""Planning mode: where to put the tripods, and what the floor coverage becomes.

A :class:`Planner` starts from the sensor poses the rig reports (each node's
``T_world_sensor``: the simulator's truth now, a calibration's result later) laid into a
lab layout (floor markers, walkway, room of :func:`engine.sim.rig.default_avenue_rig`,
the simulated lab). Moving a planned sensor updates only that sensor's coverage layer
(:class:`engine.coverage.CoverageModel`), fast enough for live dragging in the 3D view.
The planned rig can be saved as a simulator rig file and printed as a placement sheet
(distance and bearing of every tripod from marker 1).
"""

from __future__ import annotations

import dataclasses
import re
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from engine.coverage import (
    SENSOR_MODELS,
    CoverageMap,
    CoverageModel,
    Grid,
    SensorSpec,
    coverage_image,
    placement_table,
    sensor_pose,
)
from engine.errors import InputError
from engine.sim.rig import Rig, default_avenue_rig, save_rig

RIG_NAME = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
CELL_M = 0.1


def pose_angles(T: NDArray[np.float64]) -> tuple[float, float]:
    """(yaw, pitch) in degrees of a camera pose's optical axis (+Z), as in ``sensor_pose``."""
    f = np.asarray(T, float)[:3, 2]
    return (float(np.degrees(np.arctan2(f[1], f[0]))),
            float(np.degrees(np.arcsin(np.clip(f[2], -1.0, 1.0)))))


def _range_for(model_name: str) -> tuple[float, float]:
    name = model_name.lower()
    for key in ("azure_wfov", "azure_nfov", "kinect_v1"):
        if key in name.replace(" ", "_"):
            m = SENSOR_MODELS[key]
            return m.min_range_m, m.max_range_m
    m = SENSOR_MODELS["kinect_v2"]
    return m.min_range_m, m.max_range_m


class Planner:
    """Planned sensor poses and their coverage map (thread-safe; the 3D view's callbacks
    run on viser's threads, the API on the event loop).

    Args:
        sensors: the starting sensors (id, pose, field of view, range).
        layout: lab layout (markers, walkway, room) for the view and the saved rig file.
        source: where the starting poses came from, shown to the user.
    """

    def __init__(self, sensors: Sequence[SensorSpec], layout: Rig | None = None,
                 source: str = "rig") -> None:
        if not sensors:
            raise InputError("no sensor has a known pose yet: start the nodes (or calibrate) "
                             "before planning")
        self.layout = layout or default_avenue_rig(None)
        self.source = source
        self.initial = {s.id: s for s in sensors}
        xy = np.array([s.T_world_sensor[:2, 3] for s in sensors])
        w = self.layout.walkway
        ends = np.stack([np.asarray(w.start, float)[:2], np.asarray(w.end, float)[:2]])
        pts = np.vstack([xy, ends])
        lo = np.floor(pts.min(axis=0) - 1.5)
        hi = np.ceil(pts.max(axis=0) + 1.5)
        self.grid = Grid(float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]), CELL_M)
        axis = np.asarray(w.direction, float)[:2]
        self._lock = threading.Lock()
        self.model = CoverageModel(list(sensors), self.grid, walkway_axis=axis)
        self.map: CoverageMap = self.model.map()
        self.version = 0
        self.listeners: list[Any] = []  # called with the planner after every change

    @property
    def sensors(self) -> list[SensorSpec]:
        return list(self.model.sensors)

    def move(self, sensor_id: str, T_world_sensor: NDArray[np.float64] | None = None, *,
             position: Sequence[float] | None = None, yaw_deg: float | None = None,
             pitch_deg: float | None = None) -> CoverageMap:
        """Re-pose one planned sensor (a full pose, or position/yaw/pitch changes)."""
        with self._lock:
            cur = self.model.sensors[self.model.index(sensor_id)]
            if T_world_sensor is None:
                yaw0, pitch0 = pose_angles(cur.T_world_sensor)
                pos = np.asarray(position if position is not None else cur.T_world_sensor[:3, 3],
                                 float)
                if pos.shape != (3,) or not np.isfinite(pos).all():
                    raise InputError("position must be three finite numbers (x, y, z) in metres")
                T_world_sensor = sensor_pose(pos, yaw0 if yaw_deg is None else yaw_deg,
                                             pitch0 if pitch_deg is None else pitch_deg)
            T_world_sensor = np.asarray(T_world_sensor, float)
            if T_world_sensor.shape != (4, 4) or not np.isfinite(T_world_sensor).all():
                raise InputError("a sensor pose must be a finite 4×4 matrix")
            height = float(T_world_sensor[2, 3])
            if not 0.1 <= height <= 4.0:
                raise InputError(f"sensor height {height:.2f} m is outside 0.1–4 m; tripods "
                                 "stand on the floor")
            self.map = self.model.move_sensor(sensor_id, T_world_sensor)
            self.version += 1
        for cb in list(self.listeners):
            cb(self)
        return self.map

    def reset(self) -> CoverageMap:
        """Back to the rig's poses."""
        with self._lock:
            for sid, s in self.initial.items():
                self.model.move_sensor(sid, s.T_world_sensor)
            self.map = self.model.map()
            self.version += 1
        for cb in list(self.listeners):
            cb(self)
        return self.map

    def summary(self) -> dict[str, Any]:
        """JSON-ready state: sensors (pose, yaw/pitch), coverage fractions, grid."""
        with self._lock:
            cmap, sensors = self.map, list(self.model.sensors)
        out = []
        for s in sensors:
            yaw, pitch = pose_angles(s.T_world_sensor)
            moved = not np.allclose(s.T_world_sensor, self.initial[s.id].T_world_sensor,
                                    atol=1e-6)
            pos = [round(float(v), 4) for v in s.T_world_sensor[:3, 3]]
            out.append({"id": s.id, "position": pos,
                        "yaw_deg": round(yaw, 2), "pitch_deg": round(pitch, 2),
                        "moved": bool(moved)})
        g = self.grid
        walk = self.layout.walkway
        on_walk = self._walkway_mask()
        return {"source": self.source, "version": self.version, "sensors": out,
                "grid": {"x0": g.x0, "x1": g.x1, "y0": g.y0, "y1": g.y1, "cell": g.cell},
                "walkway": {"start": np.asarray(walk.start, float).tolist(),
                            "end": np.asarray(walk.end, float).tolist(), "width": walk.width},
                "covered_fraction": round(cmap.fraction(~cmap.blind), 4),
                "two_sided_fraction": round(cmap.fraction(cmap.two_sided), 4),
                "walkway_covered_fraction": round(float((~cmap.blind)[on_walk].mean()), 4),
                "walkway_two_sided_fraction": round(float(cmap.two_sided[on_walk].mean()), 4)}

    def _walkway_mask(self) -> NDArray[np.bool_]:
        w = self.layout.walkway
        x, y = self.grid.centres()
        X, Y = np.meshgrid(x, y)
        a = np.asarray(w.start, float)[:2]
        d = np.asarray(w.direction, float)[:2]
        d = d / np.linalg.norm(d)
        rel = np.stack([X - a[0], Y - a[1]], axis=-1)
        along = rel @ d
        across = rel @ np.array([-d[1], d[0]])
        mask = (along >= 0) & (along <= w.length) & (np.abs(across) <= w.width / 2)
        return mask if mask.any() else np.ones_like(mask)

    def image(self, pixels_per_cell: int = 4) -> NDArray[np.uint8]:
        """RGB coverage image (north-up) with the sensors drawn as dots with their ids."""
        with self._lock:
            cmap, sensors = self.map, list(self.model.sensors)
        img = np.ascontiguousarray(coverage_image(cmap, pixels_per_cell))
        g = self.grid
        ppm = pixels_per_cell / g.cell
        H = img.shape[0]

        def px(x: float, y: float) -> tuple[int, int]:
            return round((x - g.x0) * ppm), round(H - (y - g.y0) * ppm)

        w = self.layout.walkway
        a, b = np.asarray(w.start, float), np.asarray(w.end, float)
        cv2.line(img, px(a[0], a[1]), px(b[0], b[1]), (60, 60, 60), 1, cv2.LINE_AA)
        for s in sensors:
            x, y = s.T_world_sensor[:2, 3]
            yaw, _ = pose_angles(s.T_world_sensor)
            c = px(x, y)
            tip = px(x + 0.5 * np.cos(np.radians(yaw)), y + 0.5 * np.sin(np.radians(yaw)))
            cv2.line(img, c, tip, (0, 0, 0), 2, cv2.LINE_AA)
            cv2.circle(img, c, 6, (0, 0, 0), -1, cv2.LINE_AA)
            cv2.putText(img, s.id, (c[0] + 8, c[1] - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                        (0, 0, 0), 1, cv2.LINE_AA)
        o = px(0.0, 0.0)
        cv2.drawMarker(img, o, (0, 0, 0), cv2.MARKER_CROSS, 14, 2)
        return img

    def png(self) -> bytes:
        """:meth:`image` as PNG bytes."""
        ok, buf = cv2.imencode(".png", cv2.cvtColor(self.image(), cv2.COLOR_RGB2BGR))
        if not ok:
            raise RuntimeError("PNG encoding failed")
        return buf.tobytes()

    def placement_rows(self) -> list[dict[str, Any]]:
        """Placement sheet rows (cm and degrees, for people)."""
        return [{"id": r.id, "distance_cm": round(100 * r.distance_m, 1),
                 "bearing_deg": round(r.bearing_deg, 1), "height_cm": round(100 * r.height_m, 1),
                 "yaw_deg": round(r.yaw_deg, 1), "pitch_deg": round(r.pitch_deg, 1)}
                for r in placement_table(self.sensors)]

    def planned_rig(self) -> Rig:
        """The lab layout with the planned sensor poses (sensors not in the layout are added
        with default simulator settings)."""
        by_id = {s.id: s for s in self.layout.sensors}
        sims = []
        from engine.sim.rig import SimSensor

        for s in self.sensors:
            base = by_id.get(s.id)
            sims.append(dataclasses.replace(base, T_world_sensor=s.T_world_sensor.copy())
                        if base is not None else SimSensor(id=s.id,
                                                            T_world_sensor=s.T_world_sensor.copy()))
        return dataclasses.replace(self.layout, sensors=sims)

    def save(self, folder: Path, name: str) -> Path:
        """Save the planned rig as ``<folder>/<name>.toml`` (a simulator rig file)."""
        if not RIG_NAME.match(name):
            raise InputError("rig name: use 1–64 letters, digits, '-' or '_'")
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"{name}.toml"
        save_rig(self.planned_rig(), path)
        return path


def sensors_from_nodes(nodes: Sequence[Any]) -> list[SensorSpec]:
    """Coverage sensors of the registry's nodes that reported a pose."""
    out = []
    for s in sorted(nodes, key=lambda n: n.id):
        T = s.sensor.T_world_sensor
        if T is None:
            continue
        rmin, rmax = _range_for(s.sensor.model)
        out.append(SensorSpec(s.id, np.asarray(T, float), float(s.sensor.fov_deg[0]),
                              float(s.sensor.fov_deg[1]), rmin, rmax))
    return out
