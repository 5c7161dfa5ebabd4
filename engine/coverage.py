"""Sensor visibility on the floor: active-area trapezoid, coverage map, placement sheet.

A depth sensor is modelled as a pyramidal frustum (horizontal × vertical field of view)
cut by its depth range (``min_range_m ≤ z ≤ max_range_m``, ``z`` = depth along the optical
axis, which is what a Kinect measures). A standing person is a vertical cylinder from the
floor (z = 0) to ``body_height_m`` with radius ``body_radius_m``. A sensor "sees the whole
body" at a floor cell when the entire cylinder lies inside the frustum.

The test is exact rather than sampled: the frustum is the intersection of six half-spaces
``a·p ≤ b`` and the cylinder is the convex hull of its two horizontal end discs, so the
cylinder is inside iff both discs are, and a disc of centre ``c`` and radius ``r`` is
inside ``a·p ≤ b`` iff ``a·c + r‖a_xy‖ ≤ b``. Every floor cell × 2 discs × 6 planes ×
every sensor is therefore one small broadcast numpy expression — equivalent to
infinitely many feet-to-head sample points, and fast enough for live tripod dragging.

Frames: world is right-handed, Z up, origin at marker 1. ``T_world_sensor`` maps sensor
camera coordinates (OpenCV/Kinect depth convention: +Z forward, +X right, +Y down) to the
world. Occlusion by other people or furniture is not modelled.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.errors import InputError
from engine.geometry import look_at

FloatArray = NDArray[np.float64]

# --------------------------------------------------------------------------- models


@dataclass(frozen=True)
class SensorModel:
    """Field of view and depth range of a depth-sensor type."""

    name: str
    hfov_deg: float
    vfov_deg: float
    min_range_m: float
    max_range_m: float


#: Presets. Kinect v1 as in seed 004 (57°×43°, range limited to 4 m); Kinect v2 depth
#: camera; Azure Kinect depth modes (WFOV's 120° is a circular fisheye field, modelled
#: here as the enclosing pyramid, so its coverage is an upper bound).
SENSOR_MODELS: dict[str, SensorModel] = {
    m.name: m
    for m in (
        SensorModel("kinect_v1", 57.0, 43.0, 0.8, 4.0),
        SensorModel("kinect_v2", 70.6, 60.0, 0.5, 4.5),
        SensorModel("azure_nfov", 75.0, 65.0, 0.5, 3.86),
        SensorModel("azure_wfov", 120.0, 120.0, 0.25, 2.88),
    )
}


@dataclass(frozen=True)
class SensorSpec:
    """One placed sensor.

    Attributes:
        id: Sensor identifier (any string).
        T_world_sensor: 4×4 pose, camera frame +Z forward, +X right, +Y down.
        hfov_deg: Full horizontal field of view.
        vfov_deg: Full vertical field of view.
        min_range_m: Nearest usable depth along the optical axis.
        max_range_m: Farthest usable depth along the optical axis.
    """

    id: str
    T_world_sensor: FloatArray
    hfov_deg: float = 70.6
    vfov_deg: float = 60.0
    min_range_m: float = 0.5
    max_range_m: float = 4.5

    def __post_init__(self) -> None:
        T = np.asarray(self.T_world_sensor, dtype=float)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise InputError(f"sensor {self.id!r}: T_world_sensor must be a finite 4×4 matrix")
        R = T[:3, :3]
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise InputError(f"sensor {self.id!r}: T_world_sensor rotation is not a rotation")
        if not (0 < self.hfov_deg < 180 and 0 < self.vfov_deg < 180):
            raise InputError(
                f"sensor {self.id!r}: fields of view must be in (0°, 180°), got "
                f"{self.hfov_deg}°×{self.vfov_deg}°"
            )
        if not (0 <= self.min_range_m < self.max_range_m):
            raise InputError(
                f"sensor {self.id!r}: need 0 ≤ min_range_m < max_range_m, got "
                f"{self.min_range_m}–{self.max_range_m} m"
            )
        object.__setattr__(self, "T_world_sensor", T)

    @classmethod
    def from_model(cls, id: str, T_world_sensor: ArrayLike, model: str | SensorModel
                   ) -> SensorSpec:
        """A sensor of a preset type (``SENSOR_MODELS`` key or a :class:`SensorModel`).

        Args:
            id: Sensor id.
            T_world_sensor: Its 4×4 pose.
            model: A ``SENSOR_MODELS`` key (e.g. ``"kinect_v2"``) or a :class:`SensorModel`.

        Returns:
            The spec with the model's fields of view and range.

        Raises:
            InputError: unknown model.
        """
        if isinstance(model, str):
            if model not in SENSOR_MODELS:
                raise InputError(f"unknown sensor model {model!r}; known: {sorted(SENSOR_MODELS)}")
            model = SENSOR_MODELS[model]
        return cls(id, np.asarray(T_world_sensor, dtype=float), model.hfov_deg, model.vfov_deg,
                   model.min_range_m, model.max_range_m)


SensorLike = SensorSpec | tuple  # (id, T_world_sensor, fov_h, fov_v, min_range, max_range)


def as_sensor(s: SensorLike) -> SensorSpec:
    """Accept a :class:`SensorSpec` or an ``(id, T, fov_h, fov_v, min_r, max_r)`` tuple.

    Args:
        s: The sensor: a spec, or a tuple of id, ``T_world_sensor`` (4×4), horizontal and
            vertical field of view (deg) and depth range (m).

    Returns:
        The :class:`SensorSpec`.

    Raises:
        InputError: a tuple of another shape or a bad pose.
    """
    if isinstance(s, SensorSpec):
        return s
    if isinstance(s, tuple) and len(s) == 6:
        sid, T, fh, fv, rmin, rmax = s
        return SensorSpec(str(sid), np.asarray(T, dtype=float), float(fh), float(fv),
                          float(rmin), float(rmax))
    raise InputError(
        "a sensor must be a SensorSpec or a tuple (id, T_world_sensor, fov_h_deg, fov_v_deg, "
        "min_range_m, max_range_m)"
    )


def sensor_pose(position: ArrayLike, yaw_deg: float, pitch_deg: float = 0.0,
                roll_deg: float = 0.0) -> FloatArray:
    """``T_world_sensor`` of a sensor at ``position`` looking along a heading.

    Args:
        position: Sensor optical centre in the world (m).
        yaw_deg: Heading of the optical axis, counter-clockwise from world +X.
        pitch_deg: Elevation of the optical axis; negative = tilted down.
        roll_deg: Rotation about the optical axis (clockwise as seen by the sensor).

    Returns:
        4×4 transform, camera frame +Z forward, +X right, +Y down.
    """
    p = np.asarray(position, dtype=float)
    if p.shape != (3,):
        raise InputError("sensor position must be (x, y, z) in metres")
    if abs(pitch_deg) >= 89.9:
        raise InputError("sensor pitch must be within ±89.9°; a sensor looking straight "
                         "up or down has no heading")
    y, pch = np.radians(yaw_deg), np.radians(pitch_deg)
    f = np.array([np.cos(pch) * np.cos(y), np.cos(pch) * np.sin(y), np.sin(pch)])
    T = look_at(p, p + f)
    if roll_deg:
        c, s = np.cos(np.radians(roll_deg)), np.sin(np.radians(roll_deg))
        T[:3, :3] = T[:3, :3] @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return T


def avenue_rig(n_rows: int = 3, row_spacing_m: float = 2.5, width_m: float = 2.0,
               inward_deg: float = 35.0, height_m: float = 1.0, pitch_deg: float = -8.0,
               first_row_x_m: float = 2.4, facing: int = -1, model: str = "kinect_v2"
               ) -> list[SensorSpec]:
    """The seed-000 "avenue": sensor pairs in rows along the walkway (X), turned inwards.

    Rows sit at ``x = first_row_x_m + k·row_spacing_m``, the two sensors of a row at
    ``y = ±width_m/2``, each looking along ``facing``·X (−1: towards a walker who walks
    along +X) rotated ``inward_deg`` towards the walkway centre line and pitched by
    ``pitch_deg``. Defaults and ids (``S1``… with odd ids on +Y, the left of a walker
    going +X) match the simulated lab's default rig (``engine.sim.rig``).

    Args:
        n_rows: Rows of two sensors.
        row_spacing_m: Distance between rows along X, m.
        width_m: Distance between a row's two sensors, m.
        inward_deg: Turn towards the centre line, degrees.
        height_m: Sensor height above the floor, m.
        pitch_deg: Pitch, degrees (negative: down).
        first_row_x_m: X of the first row, m.
        facing: ``-1`` or ``+1``: the optical axes' direction along X.
        model: A ``SENSOR_MODELS`` key (field of view, range).

    Returns:
        The sensors, ``S1`` ... in row order.

    Raises:
        InputError: ``n_rows`` < 1 or ``facing`` not ±1.
    """
    if n_rows < 1 or facing not in (-1, 1):
        raise InputError("avenue_rig: need n_rows ≥ 1 and facing ±1")
    base = 0.0 if facing > 0 else 180.0
    out = []
    for k in range(n_rows):
        x = first_row_x_m + k * row_spacing_m
        for j, y in enumerate((width_m / 2, -width_m / 2)):
            # turning inwards = towards y = 0: sign depends on side and facing
            turn = -np.sign(y) * facing * inward_deg
            T = sensor_pose((x, y, height_m), base + turn, pitch_deg)
            out.append(SensorSpec.from_model(f"S{2 * k + j + 1}", T, model))
    return out


def sensors_from_rig(rig: object) -> list[SensorSpec]:
    """Sensor specs of a simulated or saved rig (``engine.sim.rig.Rig``-like object).

    Duck-typed: needs ``rig.sensors`` with ``id``, ``T_world_sensor`` and a ``model``
    carrying ``depth_hfov_deg``, ``depth_vfov_deg``, ``range_min_m``, ``range_max_m``.

    Args:
        rig: The rig.

    Returns:
        One :class:`SensorSpec` per sensor, in rig order.

    Raises:
        InputError: the rig has no sensors.
    """
    out = []
    for s in getattr(rig, "sensors", []):
        m = s.model
        out.append(SensorSpec(str(s.id), np.asarray(s.T_world_sensor, dtype=float),
                              float(m.depth_hfov_deg), float(m.depth_vfov_deg),
                              float(m.range_min_m), float(m.range_max_m)))
    if not out:
        raise InputError("the rig has no sensors")
    return out


# ------------------------------------------------------------------ half-space geometry


def _frustum_halfspaces(s: SensorSpec) -> tuple[FloatArray, FloatArray]:
    """World half-spaces ``A p ≤ b`` (6×3, 6) of a sensor's frustum."""
    th = np.tan(np.radians(s.hfov_deg) / 2)
    tv = np.tan(np.radians(s.vfov_deg) / 2)
    A_cam = np.array([
        [1.0, 0.0, -th], [-1.0, 0.0, -th],   # |x| ≤ z·tan(h/2)
        [0.0, 1.0, -tv], [0.0, -1.0, -tv],   # |y| ≤ z·tan(v/2)
        [0.0, 0.0, -1.0], [0.0, 0.0, 1.0],   # min ≤ z ≤ max
    ])
    b_cam = np.array([0.0, 0.0, 0.0, 0.0, -s.min_range_m, s.max_range_m])
    R = s.T_world_sensor[:3, :3]
    t = s.T_world_sensor[:3, 3]
    # a_c·R^T(p − t) ≤ b  ⇔  (R a_c)·p ≤ b + (R a_c)·t
    A = A_cam @ R.T
    return A, b_cam + A @ t


def _stack_halfspaces(sensors: Sequence[SensorSpec]) -> tuple[FloatArray, FloatArray]:
    A = np.empty((len(sensors), 6, 3))
    b = np.empty((len(sensors), 6))
    for i, s in enumerate(sensors):
        A[i], b[i] = _frustum_halfspaces(s)
    return A, b


def _visible_layers(A: FloatArray, b: FloatArray, X: FloatArray, Y: FloatArray,
                    body_height_m: float, body_radius_m: float) -> NDArray[np.bool_]:
    """(S, Ny, Nx) whole-cylinder visibility for half-space stacks (S, 6, 3), (S, 6)."""
    # slack of the feet disc (z = 0): b − a_x X − a_y Y − r‖a_xy‖ ≥ 0, head disc adds −a_z H
    ax = A[..., 0][..., None, None]
    ay = A[..., 1][..., None, None]
    az = A[..., 2][..., None, None]
    rad = (body_radius_m * np.hypot(A[..., 0], A[..., 1]))[..., None, None]
    slack = b[..., None, None] - rad - ax * X - ay * Y  # (S, 6, Ny, Nx)
    feet = slack >= 0
    head = slack >= az * body_height_m
    return np.all(feet & head, axis=1)


# ------------------------------------------------------------------------ trapezoid


@dataclass(frozen=True)
class Trapezoid:
    """Floor area where one sensor sees a whole standing body.

    Distances are horizontal, from the point on the floor below the sensor along its
    heading. Seed 004 calls ``B = D·tan(θh/2)`` the trapezoid's "bases" (138 and 217 cm
    for Kinect v1 at 1 m); that formula is the *half* width of the field at distance D,
    so both are given: ``near_half_width_m`` reproduces the paper, ``near_width_m`` is the
    full width across.

    Attributes:
        near_m: Nearest distance with the whole body visible (paper's Dmin).
        far_m: Farthest distance (paper's Dmax).
        near_width_m: Full width of the area at ``near_m``.
        far_width_m: Full width at ``far_m``.
        polygon: ``(K, 2)`` floor polygon (counter-clockwise) in the sensor's floor frame:
            x forward along the heading, y to the sensor's left. With tilt it may have
            more than four corners.
    """

    near_m: float
    far_m: float
    near_width_m: float
    far_width_m: float
    polygon: FloatArray = field(repr=False)

    @property
    def near_half_width_m(self) -> float:
        """Half the near edge's width (m)."""
        return self.near_width_m / 2

    @property
    def far_half_width_m(self) -> float:
        """Half the far edge's width (m)."""
        return self.far_width_m / 2

    @property
    def depth_m(self) -> float:
        """Trapezoid height (far − near), the paper's 146 cm."""
        return self.far_m - self.near_m

    def polygon_world(self, T_world_floor: ArrayLike) -> FloatArray:
        """Polygon corners (K, 3) on the floor in the world, given the floor frame pose.

        Args:
            T_world_floor: 4×4 pose of the sensor's floor frame (origin below the sensor, x
                along its heading, z up).

        Returns:
            ``(K, 3)`` world points, m (z = 0 in the floor frame).
        """
        T = np.asarray(T_world_floor, dtype=float)
        P = np.column_stack([self.polygon, np.zeros(len(self.polygon))])
        return P @ T[:3, :3].T + T[:3, 3]


def _clip_polygon(poly: FloatArray, a: FloatArray, b: float) -> FloatArray:
    """Sutherland–Hodgman clip of a convex polygon to the half-plane ``a·p ≤ b``."""
    out: list[FloatArray] = []
    n = len(poly)
    for i in range(n):
        p, q = poly[i], poly[(i + 1) % n]
        fp, fq = a @ p - b, a @ q - b
        if fp <= 0:
            out.append(p)
        if fp * fq < 0:
            out.append(p + (q - p) * (fp / (fp - fq)))
    return np.array(out).reshape(-1, 2)


def _drop_collinear(poly: FloatArray, tol: float = 1e-9) -> FloatArray:
    """Remove repeated and collinear vertices that clipping leaves behind."""
    keep = []
    n = len(poly)
    for i in range(n):
        p, q, r = poly[i - 1], poly[i], poly[(i + 1) % n]
        cross = (q[0] - p[0]) * (r[1] - q[1]) - (q[1] - p[1]) * (r[0] - q[0])
        if abs(cross) > tol and np.linalg.norm(q - p) > tol:
            keep.append(q)
    return np.array(keep).reshape(-1, 2)


def _width_at(poly: FloatArray, x: float) -> float:
    """Extent in y of a convex polygon at abscissa ``x`` (0 if it misses)."""
    ys = []
    n = len(poly)
    for i in range(n):
        p, q = poly[i], poly[(i + 1) % n]
        lo, hi = min(p[0], q[0]), max(p[0], q[0])
        if hi - lo < 1e-12:
            if abs(p[0] - x) < 1e-9:
                ys += [p[1], q[1]]
        elif lo - 1e-9 <= x <= hi + 1e-9:
            u = (x - p[0]) / (q[0] - p[0])
            ys.append(p[1] + u * (q[1] - p[1]))
    return float(max(ys) - min(ys)) if ys else 0.0


def _floor_polygon(A: FloatArray, b: FloatArray, centre_xy: FloatArray, half_size: float,
                   body_height_m: float, body_radius_m: float) -> FloatArray:
    """Floor region (K, 2) where the body cylinder satisfies all half-spaces ``A p ≤ b``.

    Each end-disc constraint is linear in the floor position, so the region is the
    intersection of half-planes: a convex polygon (empty (0, 2) when there is none).
    """
    cx, cy = centre_xy
    h = half_size
    poly = np.array([[cx - h, cy - h], [cx + h, cy - h], [cx + h, cy + h], [cx - h, cy + h]])
    rad = body_radius_m * np.hypot(A[:, 0], A[:, 1])
    for z in (0.0, body_height_m):
        for a, bb, r in zip(A, b, rad, strict=True):
            poly = _clip_polygon(poly, a[:2], bb - r - a[2] * z)
            if len(poly) < 3:
                return np.zeros((0, 2))
    return _drop_collinear(poly)


def active_area_polygon(sensor: SensorLike, body_height_m: float = 1.8,
                        body_radius_m: float = 0.2) -> FloatArray:
    """World floor polygon ``(K, 3)`` (z = 0, counter-clockwise) where a placed sensor
    sees a whole standing body — the active area to draw on the floor of the 3D view.

    Returns an empty ``(0, 3)`` array when there is no such spot (e.g. tilted too far).

    Args:
        sensor: The placed sensor (spec or tuple, see :func:`as_sensor`).
        body_height_m: Height of the standing body, m.
        body_radius_m: Its radius, m.

    Returns:
        ``(K, 3)`` world polygon, m (z = 0).
    """
    s = as_sensor(sensor)
    A, b = _frustum_halfspaces(s)
    poly = _floor_polygon(A, b, s.T_world_sensor[:2, 3], 2.0 * s.max_range_m + 1.0,
                          body_height_m, body_radius_m)
    return np.column_stack([poly, np.zeros(len(poly))])


def active_area_trapezoid(height_m: float, vfov_deg: float, hfov_deg: float,
                          min_range_m: float, max_range_m: float, body_height_m: float = 1.8,
                          tilt_deg: float = 0.0, body_radius_m: float = 0.0) -> Trapezoid:
    """Floor area where a sensor sees a whole standing body (seed 004, section III.A).

    The paper's assumptions, which this reproduces for ``tilt_deg = 0`` and
    ``body_radius_m = 0``: sensor ``height_m`` above a flat floor, optical axis level; the
    nearest spot is where the feet enter the lower half of the vertical field,
    ``Dmin = h / tan(θv/2)`` (the head, lower than ``h + Dmin·tan(θv/2)``, is then
    visible too), unless the head or ``min_range_m`` is the tighter limit; the farthest
    is the range limit (depth along the axis); the sides are the horizontal field.
    Kinect v1 at 1 m: 254 cm, 400 cm, half-widths 138 and 217 cm.

    Args:
        height_m: Sensor optical centre above the floor.
        vfov_deg: Full vertical field of view.
        hfov_deg: Full horizontal field of view.
        min_range_m: Nearest usable depth.
        max_range_m: Farthest usable depth.
        body_height_m: Height of the person (head top).
        tilt_deg: Downward tilt of the optical axis (negative tilts up).
        body_radius_m: Radius of the body cylinder (0 = a line, as in the paper).

    Returns:
        Near and far distances and widths (m) and the floor polygon in the sensor's
        floor frame (:class:`Trapezoid`).

    Raises:
        InputError: impossible geometry, or no spot where the whole body is visible.
    """
    if height_m <= 0 or body_height_m <= 0 or body_radius_m < 0:
        raise InputError("active_area_trapezoid: height_m and body_height_m must be > 0 "
                         "and body_radius_m ≥ 0")
    s = SensorSpec("trapezoid", sensor_pose((0.0, 0.0, height_m), 0.0, -tilt_deg),
                   hfov_deg, vfov_deg, min_range_m, max_range_m)
    A, b = _frustum_halfspaces(s)
    # body at floor point (x, y): each disc constraint is linear in (x, y)
    poly = _floor_polygon(A, b, np.zeros(2), 2.0 * max_range_m + 1.0, body_height_m,
                          body_radius_m)
    if len(poly) < 3:
        raise InputError(
            f"no floor spot where a {body_height_m} m body is fully visible from "
            f"{height_m} m height with {hfov_deg}°×{vfov_deg}° and range "
            f"{min_range_m}–{max_range_m} m; lower the tilt or raise the sensor"
        )
    near, far = float(poly[:, 0].min()), float(poly[:, 0].max())
    return Trapezoid(near, far, _width_at(poly, near), _width_at(poly, far), poly)


def preset_trapezoid(model: str, height_m: float = 1.0, **kwargs: float) -> Trapezoid:
    """:func:`active_area_trapezoid` for a ``SENSOR_MODELS`` preset.

    Args:
        model: A ``SENSOR_MODELS`` key (e.g. ``"kinect_v2"``).
        height_m: Sensor height above the floor, m.
        **kwargs: Further :func:`active_area_trapezoid` arguments.

    Returns:
        The trapezoid (m).

    Raises:
        InputError: unknown model.
    """
    if model not in SENSOR_MODELS:
        raise InputError(f"unknown sensor model {model!r}; known: {sorted(SENSOR_MODELS)}")
    m = SENSOR_MODELS[model]
    return active_area_trapezoid(height_m, m.vfov_deg, m.hfov_deg, m.min_range_m,
                                 m.max_range_m, **kwargs)


# ------------------------------------------------------------------------- coverage


@dataclass(frozen=True)
class Grid:
    """Floor grid ``[x0, x1] × [y0, y1]`` with square cells of ``cell`` metres."""

    x0: float
    x1: float
    y0: float
    y1: float
    cell: float

    def __post_init__(self) -> None:
        if not (self.cell > 0 and self.x1 > self.x0 and self.y1 > self.y0):
            raise InputError("grid needs x1 > x0, y1 > y0 and cell > 0 (metres)")
        if self.shape[0] * self.shape[1] > 4_000_000:
            raise InputError(f"grid of {self.shape} cells is too fine; use a larger cell")

    @property
    def shape(self) -> tuple[int, int]:
        """(Ny, Nx)."""
        return (round((self.y1 - self.y0) / self.cell), round((self.x1 - self.x0) / self.cell))

    def centres(self) -> tuple[FloatArray, FloatArray]:
        """Cell-centre coordinates ``x`` (Nx,) and ``y`` (Ny,).

        Returns:
            ``(x, y)`` in metres.
        """
        ny, nx = self.shape
        x = self.x0 + (np.arange(nx, dtype=np.float64) + 0.5) * self.cell
        y = self.y0 + (np.arange(ny, dtype=np.float64) + 0.5) * self.cell
        return x.astype(np.float64), y.astype(np.float64)


@dataclass(frozen=True)
class CoverageMap:
    """How many sensors see a whole standing body at each floor cell.

    Attributes:
        grid: The grid; arrays are indexed ``[iy, ix]`` (row = y, increasing).
        sensor_ids: Sensor order of ``visible``.
        visible: ``(S, Ny, Nx)`` bool, sensor ``s`` sees the whole body at the cell.
        counts: ``(Ny, Nx)`` number of sensors seeing the whole body.
        left: ``(Ny, Nx)`` sensors seeing it from the walker's left (+lateral side).
        right: ``(Ny, Nx)`` sensors seeing it from the walker's right.
        two_sided: ``(Ny, Nx)`` seen from both sides of the walkway (seed 000).
        blind: ``(Ny, Nx)`` no sensor sees the whole body.
    """

    grid: Grid
    sensor_ids: tuple[str, ...]
    visible: NDArray[np.bool_]
    counts: NDArray[np.int64]
    left: NDArray[np.int64]
    right: NDArray[np.int64]
    two_sided: NDArray[np.bool_]
    blind: NDArray[np.bool_]

    def fraction(self, mask: NDArray[np.bool_]) -> float:
        """Fraction of the grid's cells where ``mask`` is true.

        Args:
            mask: ``(Ny, Nx)`` bools.

        Returns:
            The fraction, 0–1.
        """
        return float(np.mean(mask))

    def to_dict(self) -> dict[str, object]:
        """JSON-ready summary and per-cell arrays (rows = y increasing) for a browser.

        Returns:
            Grid, sensor ids, per-cell counts and two-sided flags, covered and two-sided
            fractions.
        """
        g = self.grid
        return {
            "grid": {"x0": g.x0, "x1": g.x1, "y0": g.y0, "y1": g.y1, "cell": g.cell,
                     "nx": g.shape[1], "ny": g.shape[0]},
            "sensor_ids": list(self.sensor_ids),
            "counts": self.counts.tolist(),
            "two_sided": self.two_sided.astype(int).tolist(),
            "covered_fraction": self.fraction(~self.blind),
            "two_sided_fraction": self.fraction(self.two_sided),
        }


class CoverageModel:
    """Coverage map with an incremental path for live tripod dragging.

    Keeps one visibility layer and one side layer per sensor; moving a sensor
    recomputes only its layers and re-sums (an (S, Ny, Nx) reduction).

    Args:
        sensors: Placed sensors (``SensorSpec`` or 6-tuples).
        grid: Floor grid, or a tuple ``(x0, x1, y0, y1, cell)``.
        body_height_m: Standing body height.
        body_radius_m: Body cylinder radius (about half the shoulder width).
        walkway_axis: Walking direction on the floor (x, y); the walker's left is 90°
            counter-clockwise from it. Sides are the same for walking either way along it.
        min_side_angle_deg: A sensor counts for a side only when its line of sight to the
            body makes at least this angle with the walkway axis (a sensor straight ahead
            sees the front, not a side).
    """

    def __init__(self, sensors: Iterable[SensorLike], grid: Grid | tuple,
                 body_height_m: float = 1.8, body_radius_m: float = 0.2,
                 walkway_axis: ArrayLike = (1.0, 0.0), min_side_angle_deg: float = 5.0
                 ) -> None:
        self.grid = grid if isinstance(grid, Grid) else Grid(*grid)
        if body_height_m <= 0 or body_radius_m < 0:
            raise InputError("body_height_m must be > 0 and body_radius_m ≥ 0")
        self.body_height_m = float(body_height_m)
        self.body_radius_m = float(body_radius_m)
        ax = np.asarray(walkway_axis, dtype=float)
        if ax.shape != (2,) or np.linalg.norm(ax) < 1e-9:
            raise InputError("walkway_axis must be a non-zero (x, y) floor direction")
        self._axis = ax / np.linalg.norm(ax)
        self._lateral = np.array([-self._axis[1], self._axis[0]])
        self._sin_side = float(np.sin(np.radians(min_side_angle_deg)))
        x, y = self.grid.centres()
        self._X, self._Y = np.meshgrid(x, y)
        self.sensors: list[SensorSpec] = [as_sensor(s) for s in sensors]
        ids = [s.id for s in self.sensors]
        if len(set(ids)) != len(ids):
            raise InputError(f"sensor ids must be unique, got {ids}")
        ny, nx = self.grid.shape
        self._vis = np.zeros((len(self.sensors), ny, nx), dtype=bool)
        self._side = np.zeros((len(self.sensors), ny, nx), dtype=np.int8)
        if self.sensors:
            A, b = _stack_halfspaces(self.sensors)
            self._vis[:] = _visible_layers(A, b, self._X, self._Y, self.body_height_m,
                                           self.body_radius_m)
            pos = np.stack([s.T_world_sensor[:3, 3] for s in self.sensors])
            self._side[:] = self._sides(pos)

    def _sides(self, pos: FloatArray) -> NDArray[np.int8]:
        """(S, Ny, Nx): +1 sensor looks at the walker's left side, −1 right, 0 front/back."""
        dx = pos[:, 0, None, None] - self._X
        dy = pos[:, 1, None, None] - self._Y
        lat = dx * self._lateral[0] + dy * self._lateral[1]
        dist = np.hypot(dx, dy)
        side = np.where(lat > self._sin_side * dist, 1, np.where(lat < -self._sin_side * dist,
                                                                  -1, 0))
        return side.astype(np.int8)

    def index(self, sensor_id: str) -> int:
        """Position of sensor ``sensor_id`` in :attr:`sensors`.

        Args:
            sensor_id: Sensor id.

        Returns:
            Its index.

        Raises:
            InputError: no sensor has that id.
        """
        for i, s in enumerate(self.sensors):
            if s.id == sensor_id:
                return i
        raise InputError(f"no sensor {sensor_id!r} in the coverage model")

    def move_sensor(self, sensor_id: str, T_world_sensor: ArrayLike) -> CoverageMap:
        """Re-pose one sensor and return the updated map (recomputes only its layer).

        Args:
            sensor_id: Sensor id.
            T_world_sensor: Its new 4×4 pose.

        Returns:
            The updated coverage map.

        Raises:
            InputError: no sensor has that id, or a bad pose.
        """
        i = self.index(sensor_id)
        old = self.sensors[i]
        s = SensorSpec(old.id, np.asarray(T_world_sensor, dtype=float), old.hfov_deg,
                       old.vfov_deg, old.min_range_m, old.max_range_m)
        self.sensors[i] = s
        A, b = _frustum_halfspaces(s)
        self._vis[i] = _visible_layers(A[None], b[None], self._X, self._Y, self.body_height_m,
                                       self.body_radius_m)[0]
        self._side[i] = self._sides(s.T_world_sensor[None, :3, 3])[0]
        return self.map()

    def add_sensor(self, sensor: SensorLike) -> CoverageMap:
        """Add a tripod (planning mode) and return the updated map.

        Args:
            sensor: The new sensor (spec or tuple, see :func:`as_sensor`).

        Returns:
            The updated coverage map.

        Raises:
            InputError: its id is already in the model, or a bad sensor.
        """
        s = as_sensor(sensor)
        if any(o.id == s.id for o in self.sensors):
            raise InputError(f"a sensor {s.id!r} is already in the coverage model")
        A, b = _frustum_halfspaces(s)
        vis = _visible_layers(A[None], b[None], self._X, self._Y, self.body_height_m,
                              self.body_radius_m)
        self.sensors.append(s)
        self._vis = np.concatenate([self._vis, vis])
        self._side = np.concatenate([self._side, self._sides(s.T_world_sensor[None, :3, 3])])
        return self.map()

    def remove_sensor(self, sensor_id: str) -> CoverageMap:
        """Remove a tripod and return the updated map.

        Args:
            sensor_id: Sensor id.

        Returns:
            The updated coverage map.

        Raises:
            InputError: no sensor has that id.
        """
        i = self.index(sensor_id)
        del self.sensors[i]
        self._vis = np.delete(self._vis, i, axis=0)
        self._side = np.delete(self._side, i, axis=0)
        return self.map()

    def map(self) -> CoverageMap:
        """Aggregate the per-sensor layers into a :class:`CoverageMap`.

        Returns:
            The coverage map of the current sensors.
        """
        counts = self._vis.sum(axis=0, dtype=np.int64)
        left = (self._vis & (self._side > 0)).sum(axis=0, dtype=np.int64)
        right = (self._vis & (self._side < 0)).sum(axis=0, dtype=np.int64)
        return CoverageMap(self.grid, tuple(s.id for s in self.sensors), self._vis.copy(),
                           counts, left, right, (left > 0) & (right > 0), counts == 0)


def coverage_map(sensors: Iterable[SensorLike], grid: Grid | tuple, body_height_m: float = 1.8,
                 body_radius_m: float = 0.2, walkway_axis: ArrayLike = (1.0, 0.0),
                 min_side_angle_deg: float = 5.0) -> CoverageMap:
    """One-shot coverage map; see :class:`CoverageModel` for the arguments.

    Args:
        sensors: The placed sensors (specs or tuples, see :func:`as_sensor`).
        grid: The floor grid, or ``(x0, x1, y0, y1, cell)`` in metres.
        body_height_m: Height of the standing body, m.
        body_radius_m: Its radius, m.
        walkway_axis: Walking direction on the floor ``(x, y)`` (two-sided coverage is
            judged across it).
        min_side_angle_deg: Smallest angle off the walkway axis for a sensor to count as
            seeing one side.

    Returns:
        Per floor cell the number of sensors seeing a whole standing body.

    Raises:
        InputError: a bad grid or sensor.
    """
    return CoverageModel(sensors, grid, body_height_m, body_radius_m, walkway_axis,
                         min_side_angle_deg).map()


_RAMP = np.array([  # 1, 2, 3, 4, 5, 6+ sensors: pale yellow → green → blue
    [255, 237, 160], [173, 221, 142], [102, 194, 164], [44, 162, 95], [35, 132, 67],
    [8, 64, 129],
], dtype=np.uint8)
BLIND_RGB = (215, 25, 28)


def coverage_legend() -> list[tuple[str, tuple[int, int, int]]]:
    """(label, RGB) pairs explaining :func:`coverage_image` colours.

    Returns:
        ``(label, (r, g, b))`` per colour: blind first, then by sensor count, then the
        two-sided hatch.
    """
    out: list[tuple[str, tuple[int, int, int]]] = [("blind spot (no sensor sees the whole "
                                                    "body)", BLIND_RGB)]
    for k, c in enumerate(_RAMP, start=1):
        label = f"{k} sensor" + ("s" if k > 1 else "") + (" or more" if k == len(_RAMP) else "")
        out.append((label, (int(c[0]), int(c[1]), int(c[2]))))
    out.append(("white hatch: seen from both sides of the walkway", (255, 255, 255)))
    return out


def coverage_image(cmap: CoverageMap, pixels_per_cell: int = 4) -> NDArray[np.uint8]:
    """Render a coverage map as an RGB image (north-up: first row is the largest y).

    Blind cells are red ``BLIND_RGB``; covered cells follow a pale-yellow → blue ramp by
    count (6 or more share the darkest colour); two-sided cells carry a white diagonal
    hatch (every fourth pixel diagonal).

    Args:
        cmap: The coverage map.
        pixels_per_cell: Image pixels per grid cell.

    Returns:
        ``(Ny·ppc, Nx·ppc, 3)`` uint8 image.

    Raises:
        InputError: ``pixels_per_cell`` < 1.
    """
    if pixels_per_cell < 1:
        raise InputError("pixels_per_cell must be ≥ 1")
    c = cmap.counts
    img = _RAMP[np.clip(c - 1, 0, len(_RAMP) - 1)]
    img[c == 0] = BLIND_RGB
    img = np.repeat(np.repeat(img, pixels_per_cell, axis=0), pixels_per_cell, axis=1)
    two = np.repeat(np.repeat(cmap.two_sided, pixels_per_cell, 0), pixels_per_cell, 1)
    ii, jj = np.indices(two.shape)
    img[two & ((ii + jj) % 4 == 0)] = 255
    return np.ascontiguousarray(img[::-1])


# ------------------------------------------------------------------ placement sheet


@dataclass(frozen=True)
class PlacementRow:
    """One tripod on the placement sheet, relative to marker 1 (world origin).

    Attributes:
        id: Sensor id.
        distance_m: Horizontal distance of the sensor from marker 1.
        bearing_deg: Direction of the sensor from marker 1, counter-clockwise from +X.
        height_m: Optical centre above the floor.
        yaw_deg: Heading of the optical axis, counter-clockwise from +X, in (−180, 180].
        pitch_deg: Elevation of the optical axis (negative = tilted down).
    """

    id: str
    distance_m: float
    bearing_deg: float
    height_m: float
    yaw_deg: float
    pitch_deg: float


def placement_table(sensors: Iterable[SensorLike]) -> list[PlacementRow]:
    """Rows for a printed placement sheet, one per sensor, in the given order.

    Args:
        sensors: The placed sensors (specs or tuples, see :func:`as_sensor`).

    Returns:
        Per sensor its distance (m) and bearing (deg) from marker 1 (the world origin),
        height (m), yaw and pitch (deg).
    """
    rows = []
    for s in map(as_sensor, sensors):
        t = s.T_world_sensor[:3, 3]
        f = s.T_world_sensor[:3, 2]  # optical axis in the world
        rows.append(PlacementRow(
            s.id, float(np.hypot(t[0], t[1])), float(np.degrees(np.arctan2(t[1], t[0]))),
            float(t[2]), float(np.degrees(np.arctan2(f[1], f[0]))),
            float(np.degrees(np.arcsin(np.clip(f[2], -1.0, 1.0)))),
        ))
    return rows


def format_placement_table(rows: Sequence[PlacementRow]) -> str:
    """Plain-text table (cm and degrees, for people) of :func:`placement_table` rows.

    Args:
        rows: The rows.

    Returns:
        The table, one line per sensor under a header and a rule.
    """
    head = (f"{'sensor':<10}{'dist cm':>9}{'bearing °':>11}{'height cm':>11}{'yaw °':>8}"
            f"{'pitch °':>9}")
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r.id:<10}{100 * r.distance_m:>9.1f}{r.bearing_deg:>11.1f}"
                     f"{100 * r.height_m:>11.1f}{r.yaw_deg:>8.1f}{r.pitch_deg:>9.1f}")
    return "\n".join(lines)


__all__ = [
    "BLIND_RGB",
    "SENSOR_MODELS",
    "CoverageMap",
    "CoverageModel",
    "Grid",
    "PlacementRow",
    "SensorModel",
    "SensorSpec",
    "Trapezoid",
    "active_area_polygon",
    "active_area_trapezoid",
    "as_sensor",
    "avenue_rig",
    "coverage_image",
    "coverage_map",
    "format_placement_table",
    "placement_table",
    "preset_trapezoid",
    "sensor_pose",
    "sensors_from_rig",
]

