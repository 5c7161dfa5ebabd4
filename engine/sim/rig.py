"""The simulated lab: depth sensors (Kinect v2 model), floor markers, walkway and room.

The default rig reproduces the avenue of the seed paper (000, "Kinect sensor setup for
gait analysis", Figure 4): six Kinect v2 in three pairs placed 2.5 m apart along the
walking path, the two sensors of a pair 2 m apart across it and rotated inwards by about
35°, on tripods, looking along the walkway at the approaching subject so that the
tracking volumes of consecutive pairs overlap by about 2 m (theoretical tracking length
≈ 9 m).

World frame (CONTRIBUTING): right-handed, Z up, origin at floor marker 1; the walkway
runs along +X centred on y = 0, so a subject walking towards +X has the sensors at
y = +1 ("S1", "S3", "S5") on their left and those at y = −1 on their right.

Rigs are saved/loaded as TOML or JSON (:func:`save_rig`, :func:`load_rig`).
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.errors import InputError
from engine.geometry import invert_transform, look_at, make_transform, transform_points
from engine.sim.clock import MAX_FPS, MIN_FPS, SimClock

FloatArray = NDArray[np.float64]


def _intrinsics(width: int, height: int, hfov_deg: float, vfov_deg: float) -> FloatArray:
    fx = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
    fy = (height / 2.0) / math.tan(math.radians(vfov_deg) / 2.0)
    return np.array([[fx, 0.0, (width - 1) / 2.0], [0.0, fy, (height - 1) / 2.0],
                     [0.0, 0.0, 1.0]])


def _default_T_depth_color() -> FloatArray:
    # Kinect v2: the colour camera sits ≈ 5.2 cm beside the IR/depth camera, same
    # orientation (factory extrinsics are a pure ~52 mm x-translation, sub-degree rotation).
    return make_transform(np.eye(3), [-0.052, 0.0, 0.0])


@dataclass
class SensorModel:
    """A time-of-flight RGB-D sensor, with Kinect v2 defaults.

    Depth-noise defaults follow the Kinect v2 characterisations of Fankhauser et al. 2015
    ("Kinect v2 for mobile robot navigation: evaluation and modeling", ICAR) and Fürsattel
    et al. 2016 ("A comparative error analysis of current time-of-flight sensors", IEEE
    TCI): axial noise ≈ 1–1.5 mm at 1 m growing roughly quadratically to ≈ 4 mm at
    4.5 m, plus a small fraction of pixels without a return.

    Attributes:
        depth_width, depth_height: Depth image size (px).
        depth_hfov_deg, depth_vfov_deg: Depth field of view (deg).
        range_min_m, range_max_m: Valid depth range (m); outside it the pixel reads 0.
        color_width, color_height: Native colour resolution (px).
        color_hfov_deg, color_vfov_deg: Colour field of view (deg).
        color_render_width, color_render_height: Size at which the simulation renders
            colour (px); intrinsics are scaled from the native field of view.
        T_depth_color: Colour-camera pose in the depth-camera frame.
        depth_noise_a_m: Constant part of the axial depth-noise SD (m).
        depth_noise_b_per_m: Quadratic part: SD = a + b·z² (m, z in m).
        depth_dropout: Fraction of pixels randomly without return.
        flying_pixel_prob: Probability that a pixel at a depth edge reads a mixed,
            intermediate depth (ToF flying pixels; Sarbolandi et al. 2015).
    """

    depth_width: int = 512
    depth_height: int = 424
    depth_hfov_deg: float = 70.6
    depth_vfov_deg: float = 60.0
    range_min_m: float = 0.5
    range_max_m: float = 4.5
    color_width: int = 1920
    color_height: int = 1080
    color_hfov_deg: float = 84.1
    color_vfov_deg: float = 53.8
    color_render_width: int = 640
    color_render_height: int = 360
    T_depth_color: FloatArray = field(default_factory=_default_T_depth_color)
    depth_noise_a_m: float = 0.0010
    depth_noise_b_per_m: float = 0.00015
    depth_dropout: float = 0.002
    flying_pixel_prob: float = 0.3

    def depth_intrinsics(self) -> FloatArray:
        """3×3 pinhole matrix of the depth camera.

        Returns:
            ``K`` in pixels, from the depth image size and fields of view.
        """
        return _intrinsics(self.depth_width, self.depth_height, self.depth_hfov_deg,
                           self.depth_vfov_deg)

    def color_intrinsics(self, width: int | None = None, height: int | None = None) -> FloatArray:
        """3×3 pinhole matrix of the colour camera rendered at ``width × height``.

        Args:
            width: Rendered colour width, px (default: ``color_render_width``).
            height: Rendered colour height, px (default: ``color_render_height``).

        Returns:
            ``K`` in pixels.
        """
        return _intrinsics(width or self.color_render_width, height or self.color_render_height,
                           self.color_hfov_deg, self.color_vfov_deg)

    def depth_noise_sd(self, z: ArrayLike) -> FloatArray:
        """Axial depth-noise standard deviation (m) at depth ``z`` (m).

        Args:
            z: Depth(s) along the optical axis, m (any shape).

        Returns:
            ``a + b·z²`` (m), same shape.
        """
        z = np.asarray(z, dtype=float)
        return self.depth_noise_a_m + self.depth_noise_b_per_m * z * z


@dataclass
class SimSensor:
    """One simulated depth sensor with its computer's clock.

    Attributes:
        id: Sensor id ("S1".."S6" in the default rig).
        T_world_sensor: 4×4 pose of the depth camera (OpenCV frame: +Z forward, +X right,
            +Y down).
        model: Sensor model.
        clock_offset_s: Local clock reading at true time 0 (s).
        clock_drift_ppm: Local clock rate error (ppm).
        fps_nominal: Nominal frame rate (Hz).
        fps_jitter: Relative SD of the frame period (periods stay within 25–35 Hz).
    """

    id: str
    T_world_sensor: FloatArray
    model: SensorModel = field(default_factory=SensorModel)
    clock_offset_s: float = 0.0
    clock_drift_ppm: float = 0.0
    fps_nominal: float = 30.0
    fps_jitter: float = 0.05

    @property
    def clock(self) -> SimClock:
        """The sensor computer's clock."""
        return SimClock(self.clock_offset_s, self.clock_drift_ppm)

    @property
    def T_sensor_world(self) -> FloatArray:
        """Inverse of ``T_world_sensor``: world points into the depth camera frame."""
        return invert_transform(self.T_world_sensor)

    @property
    def T_world_color(self) -> FloatArray:
        """Pose of the colour camera in the world."""
        return self.T_world_sensor @ self.model.T_depth_color

    @property
    def position(self) -> FloatArray:
        """Position of the depth camera in the world, ``(3,)`` m."""
        return np.asarray(self.T_world_sensor[:3, 3], dtype=float)

    def in_depth_view(self, points_world: ArrayLike, margin_px: float = 0.0) -> NDArray[np.bool_]:
        """Whether world points project into the depth image within the valid range.

        Args:
            points_world: ``(..., 3)`` world points, m.
            margin_px: Pixels to keep clear of the image border.

        Returns:
            ``(...)`` bool mask.
        """
        p = transform_points(self.T_sensor_world, points_world)
        K = self.model.depth_intrinsics()
        z = p[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = K[0, 0] * p[..., 0] / z + K[0, 2]
            v = K[1, 1] * p[..., 1] / z + K[1, 2]
        m = self.model
        return (
            (z >= m.range_min_m) & (np.linalg.norm(p, axis=-1) <= m.range_max_m)
            & (u >= -0.5 + margin_px) & (u <= m.depth_width - 0.5 - margin_px)
            & (v >= -0.5 + margin_px) & (v <= m.depth_height - 0.5 - margin_px)
        )


@dataclass
class FloorMarker:
    """A square ArUco marker (DICT_4X4_50) lying on the floor.

    Attributes:
        id: ArUco id.
        size_m: Edge length of the black square (m).
        T_world_marker: Pose; origin at the marker centre, Z = marker normal (up), X
            along the first edge (corner 0 → corner 1 of OpenCV's corner order).
    """

    id: int
    size_m: float
    T_world_marker: FloatArray

    def corners_marker(self) -> FloatArray:
        """``(4, 3)`` corners in the marker frame, in OpenCV ArUco order.

        OpenCV orders corners top-left, top-right, bottom-right, bottom-left of the marker
        image; with the image's x along marker X and its y along marker −Y (image rows go
        "down" while the normal points up), as ``cv2.aruco`` estimatePose expects.

        Returns:
            ``(4, 3)`` corners in metres, marker frame (z = 0).
        """
        h = self.size_m / 2.0
        return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])

    def corners_world(self) -> FloatArray:
        """``(4, 3)`` world corners in OpenCV ArUco order.

        Returns:
            The corners in metres, world frame (``T_world_marker`` applied).
        """
        return transform_points(self.T_world_marker, self.corners_marker())


@dataclass
class Walkway:
    """The walking corridor: centre line from ``start`` to ``end`` and its width (m)."""

    start: FloatArray
    end: FloatArray
    width: float = 2.0

    @property
    def direction(self) -> FloatArray:
        """Unit vector from ``start`` to ``end`` (world)."""
        d = np.asarray(self.end, float) - np.asarray(self.start, float)
        return d / np.linalg.norm(d)

    @property
    def length(self) -> float:
        """Length of the centre line, m."""
        return float(np.linalg.norm(np.asarray(self.end, float) - np.asarray(self.start, float)))


@dataclass
class Room:
    """Floor rectangle ``[floor_min, floor_max]`` (x, y in m) enclosed by walls."""

    floor_min: FloatArray
    floor_max: FloatArray
    wall_height: float = 2.8


@dataclass
class Rig:
    """Sensors, floor markers, walkway and room of a simulated lab."""

    sensors: list[SimSensor]
    markers: list[FloorMarker]
    walkway: Walkway
    room: Room

    def sensor(self, id: str) -> SimSensor:
        """The sensor called ``id``.

        Args:
            id: Sensor id (``"S1"`` ...).

        Returns:
            The simulated sensor.

        Raises:
            InputError: no such sensor (the message names the known ids).
        """
        for s in self.sensors:
            if s.id == id:
                return s
        raise InputError(f"no sensor {id!r} in the rig; sensors are "
                         f"{', '.join(s.id for s in self.sensors)}")

    def marker(self, id: int) -> FloorMarker:
        """The floor marker with ArUco id ``id``.

        Args:
            id: Marker id.

        Returns:
            The floor marker.

        Raises:
            InputError: no such marker (the message lists the known ids).
        """
        for m in self.markers:
            if m.id == id:
                return m
        raise InputError(f"no floor marker {id} in the rig; markers are "
                         f"{', '.join(str(m.id) for m in self.markers)}")

    @property
    def sensor_ids(self) -> list[str]:
        """Ids of the rig's sensors, in rig order."""
        return [s.id for s in self.sensors]


# ------------------------------------------------------------------ visibility


def marker_visible(
    sensor: SimSensor,
    marker: FloorMarker,
    max_distance_m: float | None = None,
    min_cos_incidence: float = 0.22,
    min_side_px: float = 20.0,
) -> bool:
    """Whether a floor marker can be detected in the sensor's colour image.

    Geometric criterion: all four corners in front of the colour camera and inside its
    native image, the marker centre within the depth range (so its corners can also be
    located in depth), the view not more grazing than ``acos(min_cos_incidence)`` and
    every projected edge at least ``min_side_px`` native pixels long (ArUco detection at
    the rendered resolution needs roughly this much). Body occlusion is ignored.

    Args:
        sensor: The simulated sensor.
        marker: The floor marker.
        max_distance_m: Farthest marker centre, m (default: the depth range).
        min_cos_incidence: Smallest cosine between the view ray and the marker normal.
        min_side_px: Shortest projected edge, native colour pixels.

    Returns:
        True when the marker can be detected.
    """
    m = sensor.model
    T_cw = invert_transform(sensor.T_world_color)
    c = transform_points(T_cw, marker.corners_world())
    if np.any(c[:, 2] <= 0.05):
        return False
    K = m.color_intrinsics(m.color_width, m.color_height)
    uv = (c[:, :2] / c[:, 2:3]) * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    if np.any(uv < 0) or np.any(uv[:, 0] > m.color_width - 1) or np.any(
            uv[:, 1] > m.color_height - 1):
        return False
    centre = marker.T_world_marker[:3, 3]
    to_cam = sensor.T_world_color[:3, 3] - centre
    dist = float(np.linalg.norm(to_cam))
    if dist > (max_distance_m if max_distance_m is not None else m.range_max_m):
        return False
    if float(marker.T_world_marker[:3, 2] @ to_cam) / dist < min_cos_incidence:
        return False
    sides = np.linalg.norm(uv - np.roll(uv, -1, axis=0), axis=1)
    return bool(sides.min() >= min_side_px)


def marker_visibility(rig: Rig, **kwargs: Any) -> dict[int, list[str]]:
    """Marker id → ids of the sensors that see it (see :func:`marker_visible`).

    Args:
        rig: The rig.
        **kwargs: :func:`marker_visible` thresholds.

    Returns:
        For every marker the ids of the sensors that see it (possibly none).
    """
    return {mk.id: [s.id for s in rig.sensors if marker_visible(s, mk, **kwargs)]
            for mk in rig.markers}


# ------------------------------------------------------------------ default rig

#: Geometry of the seed paper's avenue (000, Figure 4).
PAIR_SPACING_M = 2.5
PAIR_WIDTH_M = 2.0
TOE_IN_DEG = 35.0
#: Tripod height of the sensor and its downward pitch; chosen so that an adult (feet to
#: head) is inside the 60° vertical field of view over most of the 0.5–4.5 m range.
TRIPOD_HEIGHT_M = 1.0
PITCH_DOWN_DEG = 8.0
#: x of the first pair: marker 1 (origin) lies 2.4 m before it, out of reach of pair 2.
FIRST_PAIR_X_M = 2.4


def sensor_pose(position: ArrayLike, yaw_deg: float, pitch_down_deg: float) -> FloatArray:
    """``T_world_sensor`` of a camera at ``position`` with a heading and a downward pitch.

    Args:
        position: ``(3,)`` camera centre in the world, m.
        yaw_deg: Heading of the optical axis, degrees from world +X, counter-clockwise.
        pitch_down_deg: Downward tilt of the optical axis, degrees.

    Returns:
        4×4 pose (camera frame: OpenCV, +Z forward, +X right, +Y down).
    """
    yaw, pitch = math.radians(yaw_deg), math.radians(pitch_down_deg)
    d = np.array([math.cos(yaw) * math.cos(pitch), math.sin(yaw) * math.cos(pitch),
                  -math.sin(pitch)])
    eye = np.asarray(position, dtype=float)
    return look_at(eye, eye + d)


def default_avenue_rig(seed: int | None = 0) -> Rig:
    """The seed paper's six-Kinect avenue with eight floor markers.

    Pairs at x = 2.4, 4.9, 7.4 m, y = ±1 m, 1 m high, optical axes pointing back along
    the walkway (towards −X, the approaching subject) rotated 35° inwards and pitched 8°
    down. Marker 1 (the world origin) lies on the walkway centre 2.4 m before the first pair,
    seen by that pair only; no marker is seen by all sensors, and the markers chain every
    sensor to marker 1 (each consecutive pair shares markers).

    Args:
        seed: Seed of the clock offsets (uniform ±0.5 s) and drifts (uniform ±100 ppm);
            ``None`` gives ideal clocks.

    Returns:
        The rig (six sensors, eight markers, the walkway along +X, the room).
    """
    rng = np.random.default_rng(seed) if seed is not None else None
    sensors: list[SimSensor] = []
    for k, x in enumerate((FIRST_PAIR_X_M, FIRST_PAIR_X_M + PAIR_SPACING_M,
                            FIRST_PAIR_X_M + 2 * PAIR_SPACING_M)):
        for j, side in enumerate((+1.0, -1.0)):
            yaw = 180.0 + side * TOE_IN_DEG  # axis rotated from −X towards the centre line
            pose = sensor_pose([x, side * PAIR_WIDTH_M / 2.0, TRIPOD_HEIGHT_M], yaw,
                               PITCH_DOWN_DEG)
            off, drift = (0.0, 0.0) if rng is None else (rng.uniform(-0.5, 0.5),
                                                        rng.uniform(-100.0, 100.0))
            sensors.append(SimSensor(id=f"S{2 * k + j + 1}", T_world_sensor=pose,
                                     clock_offset_s=float(off), clock_drift_ppm=float(drift)))
    # (x, y, yaw°) of the markers; 40 cm markers (one per A2 sheet). Chosen so that each pair shares
    # markers with the next (connected calibration graph) and none is seen by all six.
    layout = [(0.0, 0.0, 0.0), (1.0, 0.5, 20.0), (1.0, -0.5, -15.0), (2.4, 0.0, 90.0),
              (3.4, 0.5, 45.0), (3.4, -0.5, 10.0), (4.9, 0.3, 0.0), (4.9, -0.3, 60.0)]
    markers = [
        FloorMarker(id=i + 1, size_m=0.40,
                    T_world_marker=make_transform(_rot_z(math.radians(a)), [x, y, 0.0]))
        for i, (x, y, a) in enumerate(layout)
    ]
    return Rig(
        sensors=sensors,
        markers=markers,
        walkway=Walkway(start=np.array([-2.5, 0.0, 0.0]), end=np.array([8.5, 0.0, 0.0]),
                        width=PAIR_WIDTH_M),
        room=Room(floor_min=np.array([-6.0, -3.5]), floor_max=np.array([11.0, 3.5])),
    )


def _rot_z(a: float) -> FloatArray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


# ------------------------------------------------------------------ save / load


def rig_to_dict(rig: Rig) -> dict[str, Any]:
    """Plain (JSON/TOML-serialisable) representation of a rig.

    Args:
        rig: The rig.

    Returns:
        Sensors (pose, model, clock), markers, walkway and room as plain values (m, deg).
    """

    def model_dict(m: SensorModel) -> dict[str, Any]:
        d = {k: getattr(m, k) for k in SensorModel.__dataclass_fields__}
        d["T_depth_color"] = np.asarray(m.T_depth_color, float).tolist()
        return d

    return {
        "sensors": [
            {"id": s.id, "T_world_sensor": np.asarray(s.T_world_sensor, float).tolist(),
             "clock_offset_s": float(s.clock_offset_s),
             "clock_drift_ppm": float(s.clock_drift_ppm),
             "fps_nominal": float(s.fps_nominal), "fps_jitter": float(s.fps_jitter),
             "model": model_dict(s.model)}
            for s in rig.sensors
        ],
        "markers": [
            {"id": int(m.id), "size_m": float(m.size_m),
             "T_world_marker": np.asarray(m.T_world_marker, float).tolist()}
            for m in rig.markers
        ],
        "walkway": {"start": np.asarray(rig.walkway.start, float).tolist(),
                    "end": np.asarray(rig.walkway.end, float).tolist(),
                    "width": float(rig.walkway.width)},
        "room": {"floor_min": np.asarray(rig.room.floor_min, float).tolist(),
                 "floor_max": np.asarray(rig.room.floor_max, float).tolist(),
                 "wall_height": float(rig.room.wall_height)},
    }


def _get(d: Any, key: str, where: str) -> Any:
    if not isinstance(d, dict) or key not in d:
        raise InputError(f"rig file: missing field '{where}{key}'")
    return d[key]


def _num(d: Any, key: str, where: str, default: float | None = None, positive: bool = False
         ) -> float:
    if default is not None and (not isinstance(d, dict) or key not in d):
        return default
    v = _get(d, key, where)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise InputError(f"rig file: field '{where}{key}' must be a finite number, got {v!r}")
    if positive and v <= 0:
        raise InputError(f"rig file: field '{where}{key}' must be > 0, got {v!r}")
    return float(v)


def _vec(d: Any, key: str, where: str, n: int) -> FloatArray:
    v = _get(d, key, where)
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"rig file: field '{where}{key}' must be {n} numbers") from None
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise InputError(f"rig file: field '{where}{key}' must be {n} finite numbers, got {v!r}")
    return a


def _pose(d: Any, key: str, where: str) -> FloatArray:
    v = _get(d, key, where)
    try:
        T = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"rig file: field '{where}{key}' must be a 4×4 matrix") from None
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError(f"rig file: field '{where}{key}' must be a 4×4 matrix of numbers")
    R = T[:3, :3]
    if (not np.allclose(R @ R.T, np.eye(3), atol=1e-5) or abs(np.linalg.det(R) - 1) > 1e-5
            or not np.allclose(T[3], [0, 0, 0, 1])):
        raise InputError(f"rig file: field '{where}{key}' is not a rigid transform "
                         "(rotation part must be orthonormal with det +1, last row 0 0 0 1)")
    return T


def rig_from_dict(d: dict[str, Any]) -> Rig:
    """Build and validate a rig from :func:`rig_to_dict` output.

    Args:
        d: The dict (e.g. a parsed rig file).

    Returns:
        The rig.

    Raises:
        InputError: a missing or invalid field (the message names it).
    """
    sensors_raw = _get(d, "sensors", "")
    if not isinstance(sensors_raw, list) or not sensors_raw:
        raise InputError("rig file: field 'sensors' must be a non-empty list")
    sensors = []
    seen: set[str] = set()
    for i, s in enumerate(sensors_raw):
        w = f"sensors[{i}]."
        sid = _get(s, "id", w)
        if not isinstance(sid, str) or not sid:
            raise InputError(f"rig file: field '{w}id' must be a non-empty string")
        if sid in seen:
            raise InputError(f"rig file: field '{w}id' duplicates sensor id {sid!r}")
        seen.add(sid)
        md = s.get("model", {}) if isinstance(s, dict) else {}
        if not isinstance(md, dict):
            raise InputError(f"rig file: field '{w}model' must be a table")
        model = SensorModel()
        for k, f in SensorModel.__dataclass_fields__.items():
            if k not in md:
                continue
            if k == "T_depth_color":
                model.T_depth_color = _pose(md, k, w + "model.")
            elif f.type == "int":
                v = md[k]
                if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
                    raise InputError(f"rig file: field '{w}model.{k}' must be a positive integer")
                setattr(model, k, v)
            else:
                setattr(model, k, _num(md, k, w + "model."))
        if not 0 < model.range_min_m < model.range_max_m:
            raise InputError(f"rig file: '{w}model.range_min_m' must be > 0 and < range_max_m")
        fps = _num(s, "fps_nominal", w, 30.0, positive=True)
        if not MIN_FPS <= fps <= MAX_FPS:
            raise InputError(f"rig file: field '{w}fps_nominal' must be within 25–35 Hz")
        sensors.append(SimSensor(
            id=sid, T_world_sensor=_pose(s, "T_world_sensor", w), model=model,
            clock_offset_s=_num(s, "clock_offset_s", w, 0.0),
            clock_drift_ppm=_num(s, "clock_drift_ppm", w, 0.0),
            fps_nominal=fps, fps_jitter=_num(s, "fps_jitter", w, 0.05)))
    markers_raw = d.get("markers", [])
    if not isinstance(markers_raw, list):
        raise InputError("rig file: field 'markers' must be a list")
    markers = []
    ids: set[int] = set()
    for i, m in enumerate(markers_raw):
        w = f"markers[{i}]."
        mid = _get(m, "id", w)
        if isinstance(mid, bool) or not isinstance(mid, int) or mid < 0:
            raise InputError(f"rig file: field '{w}id' must be a non-negative integer")
        if mid in ids:
            raise InputError(f"rig file: field '{w}id' duplicates marker id {mid}")
        ids.add(mid)
        markers.append(FloorMarker(id=mid, size_m=_num(m, "size_m", w, positive=True),
                                   T_world_marker=_pose(m, "T_world_marker", w)))
    ww = _get(d, "walkway", "")
    walkway = Walkway(start=_vec(ww, "start", "walkway.", 3), end=_vec(ww, "end", "walkway.", 3),
                      width=_num(ww, "width", "walkway.", 2.0, positive=True))
    if walkway.length < 0.5:
        raise InputError("rig file: walkway 'start' and 'end' must be at least 0.5 m apart")
    rm = _get(d, "room", "")
    room = Room(floor_min=_vec(rm, "floor_min", "room.", 2),
                floor_max=_vec(rm, "floor_max", "room.", 2),
                wall_height=_num(rm, "wall_height", "room.", 2.8, positive=True))
    if np.any(room.floor_max <= room.floor_min):
        raise InputError("rig file: 'room.floor_max' must exceed 'room.floor_min' in x and y")
    return Rig(sensors=sensors, markers=markers, walkway=walkway, room=room)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else "nan"
    if isinstance(v, str):
        return json.dumps(v)  # a JSON string is a valid TOML basic string
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise InputError(f"cannot write {type(v).__name__} to TOML")


def _toml_table(lines: list[str], header: str, d: dict[str, Any]) -> None:
    lines.append(header)
    subtables = []
    for k, v in d.items():
        if isinstance(v, dict):
            subtables.append((k, v))
        else:
            lines.append(f"{k} = {_toml_value(v)}")
    for k, v in subtables:
        name = header.strip("[]")
        _toml_table(lines, f"[{name}.{k}]", v)


def rig_to_toml(rig: Rig) -> str:
    """TOML text of a rig (readable back with :func:`rig_from_dict` via ``tomllib``).

    Args:
        rig: The rig.

    Returns:
        The TOML text.
    """
    d = rig_to_dict(rig)
    lines = ["# gaitrig rig file: poses are 4×4 T_world_<frame> (metres), world Z up,",
             "# origin at floor marker 1; sensor frames are OpenCV (+Z forward, +Y down)."]
    for s in d["sensors"]:
        lines.append("")
        model = s.pop("model")
        lines.append("[[sensors]]")
        for k, v in s.items():
            lines.append(f"{k} = {_toml_value(v)}")
        lines.append("[sensors.model]")
        for k, v in model.items():
            lines.append(f"{k} = {_toml_value(v)}")
    for m in d["markers"]:
        lines.append("")
        lines.append("[[markers]]")
        for k, v in m.items():
            lines.append(f"{k} = {_toml_value(v)}")
    for name in ("walkway", "room"):
        lines.append("")
        _toml_table(lines, f"[{name}]", d[name])
    return "\n".join(lines) + "\n"


def save_rig(rig: Rig, path: str | Path) -> None:
    """Write a rig as TOML (``.toml``) or JSON (``.json``).

    Args:
        rig: The rig.
        path: Destination; the extension chooses the format.

    Raises:
        InputError: another extension.
    """
    p = Path(path)
    if p.suffix.lower() == ".toml":
        p.write_text(rig_to_toml(rig), encoding="utf-8")
    elif p.suffix.lower() == ".json":
        p.write_text(json.dumps(rig_to_dict(rig), indent=1), encoding="utf-8")
    else:
        raise InputError(f"rig file {p.name!r}: use a .toml or .json extension")


def load_rig(path: str | Path) -> Rig:
    """Read a rig from TOML or JSON.

    Args:
        path: A ``.toml`` or ``.json`` rig file (as :func:`save_rig` writes).

    Returns:
        The validated rig.

    Raises:
        InputError: missing file, another extension, invalid syntax or content (the
            message names the bad field).
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"rig file {str(p)!r} does not exist")
    text = p.read_text(encoding="utf-8")
    try:
        if p.suffix.lower() == ".toml":
            d = tomllib.loads(text)
        elif p.suffix.lower() == ".json":
            d = json.loads(text)
        else:
            raise InputError(f"rig file {p.name!r}: use a .toml or .json extension")
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"rig file {p.name!r} is not valid {p.suffix[1:].upper()}: {e}") from e
    if not isinstance(d, dict):
        raise InputError(f"rig file {p.name!r} must contain a table/object at top level")
    return rig_from_dict(d)
