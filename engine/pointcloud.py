"""Depth images → 3D points (optionally coloured), voxel downsampling, loaders.

Pinhole model by default (Kinect v2/PrimeSense depth maps are delivered undistorted); a
depth lens (an Azure Kinect's factory model, OpenCV coefficients) is honoured through a
per-camera table of undistorted rays (:func:`pixel_ray_table`, the Azure Kinect SDK's
"xy table"), so a frame still costs one multiply per pixel. Everything is vectorised numpy
so the live view can reuse it at frame rate: a 512×424 frame unprojects in a few
milliseconds.

Conventions: camera frame is OpenCV (+Z forward, +X right, +Y down); depth in metres
inside the engine (``depth_scale`` converts raw integer depth, e.g. 1000 for millimetres).
"""

from __future__ import annotations

import functools
import json
import re
import struct
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.errors import InputError
from engine.geometry import transform_points
from engine.wording import count

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics of one camera (pixels).

    Attributes:
        width: Image width in pixels.
        height: Image height in pixels.
        fx: Focal length along x (pixels).
        fy: Focal length along y (pixels).
        cx: Principal point x (pixels).
        cy: Principal point y (pixels).
        dist: OpenCV distortion coefficients (k1, k2, p1, p2[, k3...]); empty = none.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, ...] = ()

    @property
    def K(self) -> FloatArray:
        """3×3 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_array(self) -> FloatArray:
        """Distortion coefficients as an array (zeros(5) when none)."""
        return np.asarray(self.dist, dtype=float) if self.dist else np.zeros(5)

    @classmethod
    def from_matrix(
        cls, K: ArrayLike, width: int, height: int, dist: ArrayLike | None = None
    ) -> CameraIntrinsics:
        """Build from a 3×3 camera matrix.

        Args:
            K: 3×3 camera matrix (pixels).
            width: Image width, px.
            height: Image height, px.
            dist: OpenCV distortion coefficients, or None for a pinhole.

        Returns:
            The intrinsics.

        Raises:
            InputError: ``K`` is not 3×3.
        """
        Km = np.asarray(K, dtype=float)
        if Km.shape != (3, 3):
            raise InputError(f"camera matrix must be 3×3, got shape {Km.shape}")
        d = () if dist is None else tuple(float(x) for x in np.asarray(dist, dtype=float).ravel())
        return cls(int(width), int(height), float(Km[0, 0]), float(Km[1, 1]),
                   float(Km[0, 2]), float(Km[1, 2]), d)


def as_intrinsics(obj: object) -> CameraIntrinsics:
    """Coerce intrinsics given as :class:`CameraIntrinsics` or any object with
    ``fx, fy, cx, cy, width, height`` attributes (e.g. the simulator's) to ours.

    Args:
        obj: The intrinsics object.

    Returns:
        Our :class:`CameraIntrinsics`.

    Raises:
        InputError: the object lacks those attributes.
    """
    if isinstance(obj, CameraIntrinsics):
        return obj
    try:
        dist = getattr(obj, "dist", None)
        d = () if dist is None else tuple(float(x) for x in np.asarray(dist, dtype=float).ravel())
        return CameraIntrinsics(
            int(obj.width), int(obj.height),  # type: ignore[attr-defined]
            float(obj.fx), float(obj.fy),  # type: ignore[attr-defined]
            float(obj.cx), float(obj.cy), d,  # type: ignore[attr-defined]
        )
    except AttributeError as exc:
        raise InputError(
            f"intrinsics must have width, height, fx, fy, cx, cy; got {type(obj).__name__}"
        ) from exc


def load_intrinsics_json(path: str | Path) -> CameraIntrinsics:
    """Read Open3D-style intrinsics JSON (``width``, ``height``, column-major
    ``intrinsic_matrix``).

    Args:
        path: The JSON file.

    Returns:
        The pinhole intrinsics (pixels).

    Raises:
        InputError: missing keys or a matrix that is not 3×3.
    """
    try:
        data = json.loads(Path(path).read_text())
        m = np.asarray(data["intrinsic_matrix"], dtype=float)
        w, h = int(data["width"]), int(data["height"])
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise InputError(f"cannot read intrinsics from {path}: {exc}") from exc
    if m.size != 9:
        raise InputError(f"{path}: intrinsic_matrix must have 9 values, has {m.size}")
    K = m.reshape(3, 3).T  # Open3D stores the matrix column-major
    return CameraIntrinsics.from_matrix(K, w, h)


#: Newton steps of the ray table's undistortion (a strong lens converges in < 8)
_UNDISTORT_STEPS = 30
#: a pixel's ray counts as found when it projects back within this many pixels
_UNDISTORT_TOL_PX = 1e-6


def _lens_coefficients(dist: ArrayLike) -> FloatArray:
    """OpenCV distortion as 12 coefficients (k1, k2, p1, p2, k3, k4, k5, k6, s1..s4).

    Raises:
        InputError: not 4, 5, 8, 12 or 14 finite numbers, or a tilted sensor (14
            coefficients with a non-zero tilt), which the ray table does not model.
    """
    d = np.asarray(dist, dtype=float).ravel()
    if d.size not in (4, 5, 8, 12, 14) or not np.all(np.isfinite(d)):
        raise InputError("lens distortion must be 4, 5, 8, 12 or 14 finite OpenCV "
                         f"coefficients (k1, k2, p1, p2[, k3...]), got {d.size}")
    if d.size == 14 and np.any(d[12:] != 0):
        raise InputError("a tilted-sensor lens model (OpenCV τx, τy) is not supported for "
                         "depth unprojection; give the 12 coefficients without tilt")
    out = np.zeros(12)
    out[:min(d.size, 12)] = d[:12]
    return out


def _distort_normalised(x: FloatArray, y: FloatArray, c: FloatArray
                        ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray,
                                   FloatArray, FloatArray]:
    """OpenCV's lens model on normalised coordinates and its Jacobian.

    Returns:
        ``(xd, yd, dxd/dx, dxd/dy, dyd/dx, dyd/dy)``.
    """
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = c
    r2 = x * x + y * y
    a = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    b = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    rad = a / b
    drad = ((k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)) * b
            - a * (k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2))) / (b * b)  # d rad / d r2
    xd = x * rad + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) + r2 * (s1 + s2 * r2)
    yd = y * rad + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y + r2 * (s3 + s4 * r2)
    sx = 2.0 * (s1 + 2.0 * s2 * r2)
    sy = 2.0 * (s3 + 2.0 * s4 * r2)
    jxx = rad + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x + x * sx
    jxy = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y + y * sx
    jyx = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y + x * sy
    jyy = rad + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x + y * sy
    return xd, yd, jxx, jxy, jyx, jyy


def undistort_normalised(px: ArrayLike, intrinsics: CameraIntrinsics,
                         dist: ArrayLike | None = None) -> FloatArray:
    """Undistorted normalised coordinates ``(x/z, y/z)`` of pixels of a camera with a lens.

    Newton's method on OpenCV's lens model (radial k1-k6, tangential p1/p2, thin prism
    s1-s4) from the pinhole coordinates, to ``1e-6`` px: OpenCV's own fixed-point
    iteration (``cv2.undistortPoints``) stalls or wanders near the border of a strong
    lens. A pixel that has no ray inside the lens's valid field (no convergence, or a
    solution past the fold of the model, where the image would turn back) gets NaN.

    Args:
        px: ``(N, 2)`` pixel coordinates (pixel centres are integers, OpenCV).
        intrinsics: The camera (its ``K``; its ``dist`` when ``dist`` is None).
        dist: OpenCV distortion coefficients; None: ``intrinsics.dist``.

    Returns:
        ``(N, 2)`` normalised coordinates (camera frame, OpenCV axes), NaN where none.

    Raises:
        InputError: distortion coefficients that are not OpenCV's.
    """
    p = np.asarray(px, dtype=np.float64).reshape(-1, 2)
    xd = (p[:, 0] - intrinsics.cx) / intrinsics.fx
    yd = (p[:, 1] - intrinsics.cy) / intrinsics.fy
    d = intrinsics.dist if dist is None else dist
    if d is None or np.size(d) == 0 or not np.any(np.asarray(d, dtype=float) != 0):
        return np.stack([xd, yd], axis=1)
    c = _lens_coefficients(d)
    x, y = xd.copy(), yd.copy()
    tol = _UNDISTORT_TOL_PX / max(intrinsics.fx, intrinsics.fy)
    with np.errstate(all="ignore"):  # diverging pixels become NaN, flagged below
        for _ in range(_UNDISTORT_STEPS):
            fx_, fy_, a, b, e, f = _distort_normalised(x, y, c)
            rx, ry = xd - fx_, yd - fy_
            det = a * f - b * e
            x = x + (f * rx - b * ry) / det
            y = y + (a * ry - e * rx) / det
            if np.nanmax(np.abs(np.concatenate([rx, ry])), initial=0.0) < tol:
                break
        fx_, fy_, a, b, e, f = _distort_normalised(x, y, c)
        ok = ((np.abs(xd - fx_) < tol) & (np.abs(yd - fy_) < tol)
              & (a * f - b * e > 0) & (a + f > 0))  # past the fold the image turns back
    x[~ok] = np.nan
    y[~ok] = np.nan
    return np.stack([x, y], axis=1)


@functools.lru_cache(maxsize=16)
def _ray_table(intrinsics: CameraIntrinsics) -> FloatArray:
    u, v = np.meshgrid(np.arange(intrinsics.width, dtype=np.float64),
                       np.arange(intrinsics.height, dtype=np.float64))
    n = undistort_normalised(np.stack([u.ravel(), v.ravel()], axis=1), intrinsics)
    table = n.reshape(intrinsics.height, intrinsics.width, 2)
    table.setflags(write=False)  # shared by every caller of the cache
    return table


def pixel_ray_table(intrinsics: CameraIntrinsics, dist: ArrayLike | None = None
                    ) -> FloatArray:
    """Normalised ray ``(x/z, y/z)`` of every pixel: the point at depth ``z`` (along the
    optical axis) seen by pixel ``(u, v)`` is ``(t[v, u, 0]·z, t[v, u, 1]·z, z)``.

    Computed once per camera (cached by intrinsics, distortion and image size) as the
    Azure Kinect SDK's "xy table", so unprojecting a frame with a lens costs what a
    pinhole does. Without distortion: ``((u - cx)/fx, (v - cy)/fy)``. Pixels without a
    ray inside the lens's valid field are NaN (see :func:`undistort_normalised`).

    Args:
        intrinsics: The depth camera at the image's size.
        dist: OpenCV distortion coefficients; None: ``intrinsics.dist`` (``()``: none).

    Returns:
        ``(H, W, 2)`` float64, read-only (shared).

    Raises:
        InputError: distortion coefficients that are not OpenCV's, non-positive focal
            lengths or image size.
    """
    if intrinsics.fx <= 0 or intrinsics.fy <= 0 or intrinsics.width < 1 or intrinsics.height < 1:
        raise InputError("depth intrinsics need positive focal lengths and image size, got "
                         f"fx={intrinsics.fx}, fy={intrinsics.fy}, "
                         f"{intrinsics.width}×{intrinsics.height}")
    d = intrinsics.dist if dist is None else dist
    key = () if d is None else tuple(float(x) for x in np.asarray(d, dtype=float).ravel())
    if not any(key):
        key = ()
    else:
        _lens_coefficients(key)  # bad coefficients: a clear error, not a cached table
    return _ray_table(CameraIntrinsics(intrinsics.width, intrinsics.height, intrinsics.fx,
                                       intrinsics.fy, intrinsics.cx, intrinsics.cy, key))


def depth_to_points(
    depth: ArrayLike,
    intrinsics: CameraIntrinsics,
    depth_scale: float = 1.0,
    min_depth: float = 0.05,
    max_depth: float = 10.0,
    stride: int = 1,
    dist: ArrayLike | None = None,
) -> tuple[FloatArray, NDArray[np.int64]]:
    """Unproject a depth image to 3D points in the camera frame.

    Args:
        depth: (H, W) depth image; raw units divided by ``depth_scale`` give metres.
        intrinsics: Depth camera intrinsics (must match the image size).
        depth_scale: Raw units per metre (1000 for uint16 millimetres, 1 for metres).
        min_depth: Closer values are treated as invalid (m).
        max_depth: Farther values are treated as invalid (m).
        stride: Take every ``stride``-th pixel in both directions (fast previews).
        dist: OpenCV distortion coefficients of the depth lens (an Azure Kinect's): points
            lie on the undistorted rays of their pixels (:func:`pixel_ray_table`), depth
            along the optical axis. None (default): a pinhole, as the depth maps of most
            cameras are delivered (``intrinsics.dist`` is not applied unless passed here,
            e.g. ``dist=intr.dist``). Pixels outside the lens's valid field are dropped.

    Returns:
        ``(points (N, 3) in metres, flat pixel indices (N,) into the full image)``.

    Raises:
        InputError: wrong shape, scale or distortion coefficients.
    """
    d = np.asarray(depth)
    if d.ndim != 2:
        raise InputError(f"depth image must be 2-D (H, W), got shape {d.shape}")
    h, w = d.shape
    if (w, h) != (intrinsics.width, intrinsics.height):
        raise InputError(
            f"depth image is {w}×{h} but intrinsics are for "
            f"{intrinsics.width}×{intrinsics.height}"
        )
    if depth_scale <= 0:
        raise InputError("depth_scale must be positive (e.g. 1000 for millimetres)")
    if stride < 1:
        raise InputError("stride must be ≥ 1")
    sub = d[::stride, ::stride]
    z = sub.astype(np.float64) / depth_scale
    ok = np.isfinite(z) & (z > min_depth) & (z < max_depth)
    if dist is None:
        vs, us = np.nonzero(ok)
        zz = z[vs, us]
        u = us * stride
        v = vs * stride
        x = (u - intrinsics.cx) / intrinsics.fx * zz
        y = (v - intrinsics.cy) / intrinsics.fy * zz
    else:
        rays = pixel_ray_table(intrinsics, dist)[::stride, ::stride]
        vs, us = np.nonzero(ok & np.isfinite(rays[..., 0]))
        zz = z[vs, us]
        u = us * stride
        v = vs * stride
        x = rays[vs, us, 0] * zz
        y = rays[vs, us, 1] * zz
    pts = np.stack([x, y, zz], axis=1)
    return pts, (v * w + u).astype(np.int64)


#: a pair of neighbouring depth pixels whose 3D segment lies within this angle of the line
#: of sight is a jump across a depth edge: a floor seen from 1 m up is steeper than this
#: out to 14 m, a flying pixel between surfaces 12 cm or more apart (1 px at 1.5 m,
#: f 180 px) is flatter
JUMP_EDGE_ANGLE_DEG = 4.0


def jump_edge_pixels(depth_m: ArrayLike, rays: ArrayLike,
                     max_angle_deg: float = JUMP_EDGE_ANGLE_DEG) -> NDArray[np.bool_]:
    """Pixels behind a depth edge: time-of-flight "flying pixels" and the background pixel
    next to a silhouette.

    A time-of-flight pixel that straddles a depth edge mixes both surfaces and reads a
    depth in between (Sarbolandi et al. 2015, CVIU 139:1): in a point cloud it floats in
    the air along the line of sight behind the edge. Two neighbouring pixels (across or
    down) whose 3D segment is within ``max_angle_deg`` of the farther one's line of sight
    are a jump, not a surface, and the farther of the two is flagged (the jump-edge
    criterion of ToF mapping, e.g. May et al. 2009, J. Field Robotics 26:934, kept
    one-sided so that the near surface, e.g. a body, keeps its rim).

    Args:
        depth_m: ``(H, W)`` depth along the optical axis (m); 0 or NaN: no measurement.
        rays: ``(H, W, 2)`` normalised rays ``(x/z, y/z)`` of the pixels
            (:func:`pixel_ray_table`); NaN rays count as no measurement.
        max_angle_deg: Largest angle (degrees) between a neighbour segment and the line of
            sight that counts as a jump.

    Returns:
        ``(H, W)`` bool mask of the pixels to drop.

    Raises:
        InputError: shapes that do not match, or an angle outside (0, 90).
    """
    # float32 or float64 as given (the live view's cached rays are float32: no copy of
    # them per frame); anything else as float64
    z, r = (np.ascontiguousarray(a) if np.asarray(a).dtype in (np.float32, np.float64)
            else np.ascontiguousarray(a, dtype=np.float64) for a in (depth_m, rays))
    if z.ndim != 2 or r.shape != (*z.shape, 2):
        raise InputError(f"rays must be (H, W, 2) for a depth image of shape {z.shape}, "
                         f"got {r.shape}")
    if not 0 < max_angle_deg < 90:
        raise InputError("max_angle_deg must be between 0 and 90 degrees")
    drop = np.zeros(z.shape, dtype=np.bool_)
    _jump_edge_kernel()(z, r, float(np.cos(np.radians(max_angle_deg))), drop)
    return drop


def _jump_edge_kernel_py(z: FloatArray, r: FloatArray, cos_max: float,
                         drop: NDArray[np.bool_]) -> None:
    H, W = z.shape
    for i in range(H):
        for j in range(W):
            za = z[i, j]
            if not za > 0 or r[i, j, 0] != r[i, j, 0] or r[i, j, 1] != r[i, j, 1]:
                continue  # no measurement (0, NaN) or no ray
            for di, dj in ((0, 1), (1, 0)):  # the neighbour across, then down
                k, m = i + di, j + dj
                if k >= H or m >= W:
                    continue
                zb = z[k, m]
                if not zb > 0 or r[k, m, 0] != r[k, m, 0] or r[k, m, 1] != r[k, m, 1]:
                    continue
                ax, ay = r[i, j, 0] * za, r[i, j, 1] * za
                bx, by = r[k, m, 0] * zb, r[k, m, 1] * zb
                sx, sy, sz = bx - ax, by - ay, zb - za
                fx, fy, fz = (bx, by, zb) if zb > za else (ax, ay, za)  # the farther one
                dot = sx * fx + sy * fy + sz * fz
                n2 = (sx * sx + sy * sy + sz * sz) * (fx * fx + fy * fy + fz * fz)
                # |cos| > cos_max, squared (no roots): the segment is along the sight line
                if n2 > 0 and dot * dot > cos_max * cos_max * n2:
                    if zb > za:
                        drop[k, m] = True
                    else:
                        drop[i, j] = True


@functools.cache
def _jump_edge_kernel() -> Callable[[FloatArray, FloatArray, float, NDArray[np.bool_]],
                                    None]:
    """The jump-edge loop compiled on first use (the live view runs it on every frame)."""
    from numba import njit

    return njit(cache=True, nogil=True)(_jump_edge_kernel_py)  # type: ignore[no-any-return]


def project_points(points: ArrayLike, intrinsics: CameraIntrinsics) -> FloatArray:
    """Pinhole projection (no distortion) of camera-frame points to pixels (N, 2).

    Points with z ≤ 0 project to NaN.

    Args:
        points: ``(N, 3)`` points in the camera frame (OpenCV: +Z forward), m.
        intrinsics: The camera's pinhole intrinsics.

    Returns:
        ``(N, 2)`` pixel coordinates ``(u, v)``.
    """
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    z = p[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = intrinsics.fx * p[:, 0] / z + intrinsics.cx
        v = intrinsics.fy * p[:, 1] / z + intrinsics.cy
    uv = np.stack([u, v], axis=1)
    uv[z <= 0] = np.nan
    return uv


def rgbd_to_colored_points(
    color: ArrayLike,
    depth: ArrayLike,
    depth_intrinsics: CameraIntrinsics,
    depth_scale: float = 1000.0,
    color_intrinsics: CameraIntrinsics | None = None,
    T_color_depth: ArrayLike | None = None,
    stride: int = 1,
    max_depth: float = 10.0,
) -> tuple[FloatArray, NDArray[np.uint8]]:
    """Coloured point cloud (depth camera frame) from a depth image and a colour image.

    When the colour image is registered to depth (same size, no ``T_color_depth``), colours
    are read at the same pixel; otherwise points are transformed into the colour camera and
    projected; points outside the colour image are dropped.

    Args:
        color: (H, W, 3) uint8 image, RGB order.
        depth: (H, W) depth image.
        depth_intrinsics: Intrinsics of the depth image.
        depth_scale: Raw depth units per metre.
        color_intrinsics: Colour camera intrinsics when not registered to depth.
        T_color_depth: 4×4 depth → colour camera transform when not registered.
        stride: Pixel stride (downsampling at the source).
        max_depth: Far cut-off (m).

    Returns:
        ``(points (N, 3) float64 in metres, colours (N, 3) uint8 RGB)``.

    Raises:
        InputError: shapes that do not fit.
    """
    c = np.asarray(color)
    if c.ndim != 3 or c.shape[2] < 3:
        raise InputError(f"colour image must be (H, W, 3), got shape {c.shape}")
    pts, flat = depth_to_points(depth, depth_intrinsics, depth_scale, stride=stride,
                                max_depth=max_depth)
    if color_intrinsics is None and T_color_depth is None:
        if c.shape[:2] != np.asarray(depth).shape:
            raise InputError(
                "colour and depth differ in size; pass color_intrinsics and T_color_depth"
            )
        cols = c[..., :3].reshape(-1, 3)[flat]
        return pts, cols.astype(np.uint8)
    ci = color_intrinsics or depth_intrinsics
    T = np.eye(4) if T_color_depth is None else np.asarray(T_color_depth, dtype=float)
    uv = project_points(transform_points(T, pts), ci)
    ui = np.round(uv[:, 0])
    vi = np.round(uv[:, 1])
    ok = np.isfinite(ui) & np.isfinite(vi) & (ui >= 0) & (vi >= 0)
    ok &= (ui < c.shape[1]) & (vi < c.shape[0])
    cols = c[vi[ok].astype(np.int64), ui[ok].astype(np.int64), :3]
    return pts[ok], cols.astype(np.uint8)


def voxel_downsample(
    points: ArrayLike, voxel: float, colors: ArrayLike | None = None
) -> tuple[FloatArray, NDArray[np.uint8] | None]:
    """Average points (and colours) per cubic voxel of edge ``voxel`` metres.

    Pure numpy (sort-free unique on integer keys), so it runs without Open3D objects.

    Args:
        points: ``(N, 3)`` points, m.
        voxel: Voxel edge, m.
        colors: ``(N, 3)`` uint8 colours, or None.

    Returns:
        ``(points (M, 3), colours (M, 3) uint8 or None)``.

    Raises:
        InputError: non-positive voxel size.
    """
    if voxel <= 0:
        raise InputError("voxel size must be positive (metres)")
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    if p.shape[0] == 0:
        return p.copy(), (None if colors is None else np.zeros((0, 3), np.uint8))
    keys = np.floor(p / voxel).astype(np.int64)
    _, inv, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    m = counts.shape[0]
    # bincount per axis is ~10× faster than np.add.at for this reduction
    out: FloatArray = np.stack(
        [np.bincount(inv, p[:, k], minlength=m) for k in range(3)], axis=1
    ).astype(np.float64) / counts[:, None]
    if colors is None:
        return out, None
    c = np.asarray(colors, dtype=float).reshape(-1, 3)
    cs = np.stack(
        [np.bincount(inv, c[:, k], minlength=m) for k in range(3)], axis=1
    ).astype(np.float64) / counts[:, None]
    return out, np.clip(np.round(cs), 0, 255).astype(np.uint8)


# --------------------------------------------------------------------- file loaders


@dataclass
class PointCloudFile:
    """A point cloud read from a file, in the file's frame and units (metres expected).

    Attributes:
        points: ``(N, 3)`` float64 coordinates; non-finite rows removed.
        colors: ``(N, 3)`` uint8 RGB, or ``None`` when the file has no colour.
        normals: ``(N, 3)`` float64 unit normals, or ``None``.
        meta: provenance: ``format`` (``ply``/``pcd``), ``encoding``
            (``ascii``/``binary``/``binary_compressed``), ``coordinate_type``
            (``float32``/``float64``), ``dropped`` (non-finite rows removed).
        warnings: problems found while reading (precision lost far from the origin ...).
    """

    points: FloatArray
    colors: NDArray[np.uint8] | None
    normals: FloatArray | None
    meta: dict[str, object]
    warnings: list[str]


#: largest point-cloud file read (the whole file is read into memory)
MAX_CLOUD_BYTES = 1024 * 2**20
#: beyond this distance from the origin float32 coordinates lose millimetres (2⁻¹³ m
#: steps from 1024 m: 0.12 mm, 0.49 mm at 4-8 km)
_FLOAT32_SAFE_M = 1000.0


def load_point_cloud(path: str | Path) -> PointCloudFile:
    """Read a PLY or PCD point cloud with its colours and normals when present.

    PLY: ascii, binary little/big endian, float or double coordinates (read by Open3D).
    PCD v0.7: ``DATA ascii``, ``binary`` and ``binary_compressed`` with ``F 4``/``F 8``
    coordinates, packed ``rgb``/``rgba`` and ``normal_x…z`` (read here: Open3D 0.18-0.20
    misreads binary PCDs with 8-byte fields). Non-finite points (organised clouds' empty
    pixels) are dropped and counted. Coordinates stay float64: a cloud 5 km from the
    origin keeps its precision when the file stores doubles; float32 coordinates that far
    out are flagged in ``warnings`` (their steps are 0.5 mm).

    Args:
        path: A ``.ply`` or ``.pcd`` file.

    Returns:
        A :class:`PointCloudFile`: ``(N, 3)`` points in the file's frame and units (metres
        expected), colours and normals when present, provenance and warnings.

    Raises:
        InputError: missing, empty, oversized, damaged or unsupported file (the message
            says which formats are read).
    """
    p = Path(path)
    suf = p.suffix.lower()
    if suf not in (".ply", ".pcd"):
        raise InputError(f"{p.name}: unsupported point-cloud type {suf or '(none)'!r}; "
                         "use .ply (ascii or binary) or .pcd (ascii, binary, "
                         "binary_compressed)")
    try:
        size = p.stat().st_size
    except OSError as e:
        raise InputError(f"cannot read {p}: {e}") from None
    if size == 0:
        raise InputError(f"{p.name}: the file is empty")
    if size > MAX_CLOUD_BYTES:
        raise InputError(f"{p.name}: {size / 2**20:.0f} MB is more than the "
                         f"{MAX_CLOUD_BYTES // 2**20} MB a point cloud may have; downsample "
                         "or crop it first")
    pts, cols, nrm, meta = _read_pcd(p) if suf == ".pcd" else _read_ply(p)
    warnings: list[str] = []
    ok = np.all(np.isfinite(pts), axis=1)
    dropped = int((~ok).sum())
    meta["dropped"] = dropped
    if not ok.all():
        pts = pts[ok]
        cols = None if cols is None else cols[ok]
        nrm = None if nrm is None else nrm[ok]
        warnings.append(f"{count(dropped, 'point')} without finite coordinates (empty pixels "
                        f"of an organised cloud) {'was' if dropped == 1 else 'were'} dropped")
    if len(pts) == 0:
        raise InputError(f"{p.name}: the file holds no point with finite coordinates")
    far = float(np.max(np.abs(pts)))
    if meta.get("coordinate_type") == "float32" and far > _FLOAT32_SAFE_M:
        step = float(np.spacing(np.float32(far)))
        warnings.append(f"coordinates reach {far:.0f} m but are stored as 32-bit floats: "
                        f"steps of {step * 1000:.2g} mm; store doubles or coordinates "
                        "relative to a local origin")
    meta["format"] = suf[1:]
    return PointCloudFile(np.ascontiguousarray(pts, dtype=np.float64), cols,
                          None if nrm is None else np.asarray(nrm, dtype=np.float64),
                          meta, warnings)


def _read_ply(p: Path) -> tuple[FloatArray, NDArray[np.uint8] | None, FloatArray | None,
                                dict[str, object]]:
    """PLY through Open3D, with the header read for its encoding and coordinate type."""
    import open3d as o3d

    with p.open("rb") as fh:
        head = fh.read(4096)
    if not head.startswith(b"ply"):
        raise InputError(f"{p.name}: not a PLY file (no 'ply' magic line); export it again")
    text = head.split(b"end_header")[0].decode("ascii", "replace")
    m = re.search(r"^format\s+(\S+)", text, re.MULTILINE)
    coord = re.search(r"^property\s+(\w+)\s+x\s*$", text, re.MULTILINE)
    meta: dict[str, object] = {
        "encoding": "ascii" if m and m.group(1) == "ascii" else "binary",
        "coordinate_type": "float64" if coord and coord.group(1) in ("double", "float64")
        else "float32"}
    cloud = o3d.io.read_point_cloud(p, format="ply")
    pts = np.asarray(cloud.points, dtype=np.float64)
    if len(pts) == 0:
        raise InputError(f"{p.name}: no vertices could be read (damaged, truncated, or no "
                         "x/y/z vertex properties); export it again")
    cols = (np.clip(np.round(np.asarray(cloud.colors) * 255.0), 0, 255).astype(np.uint8)
            if cloud.has_colors() else None)
    nrm = np.asarray(cloud.normals, dtype=np.float64) if cloud.has_normals() else None
    return pts, cols, nrm, meta


_PCD_TYPES = {("F", 4): "f4", ("F", 8): "f8", ("U", 1): "u1", ("U", 2): "u2",
              ("U", 4): "u4", ("U", 8): "u8", ("I", 1): "i1", ("I", 2): "i2",
              ("I", 4): "i4", ("I", 8): "i8"}


def _read_pcd(p: Path) -> tuple[FloatArray, NDArray[np.uint8] | None, FloatArray | None,
                                dict[str, object]]:
    """A PCD v0.5-0.7 file: header, then ascii rows, packed binary rows, or LZF-compressed
    field-major binary."""
    raw = p.read_bytes()
    header: dict[str, list[str]] = {}
    pos = 0
    while pos < len(raw):
        end = raw.find(b"\n", pos)
        end = len(raw) if end < 0 else end
        line = raw[pos:end].decode("ascii", "replace").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *vals = line.split()
        header[key.upper()] = vals
        if key.upper() == "DATA":
            break
    need = ("FIELDS", "SIZE", "TYPE", "DATA")
    missing = [k for k in need if k not in header]
    if missing:
        raise InputError(f"{p.name}: not a PCD file (header lacks {', '.join(missing)}); "
                         "export it again")
    names = header["FIELDS"]
    counts = [int(c) for c in header.get("COUNT", ["1"] * len(names))]
    try:
        dts = [_PCD_TYPES[(t.upper(), int(s))] for t, s in
               zip(header["TYPE"], header["SIZE"], strict=True)]
        n = int(header["POINTS"][0]) if "POINTS" in header else (
            int(header["WIDTH"][0]) * int(header.get("HEIGHT", ["1"])[0]))
    except (KeyError, ValueError, IndexError) as e:
        raise InputError(f"{p.name}: PCD header has unsupported or inconsistent "
                         f"FIELDS/SIZE/TYPE/COUNT ({e}); export it again") from None
    if len(counts) != len(names) or not {"x", "y", "z"} <= set(names):
        raise InputError(f"{p.name}: PCD fields {names} lack x, y, z; a point cloud needs "
                         "them")
    data = header["DATA"][0].lower() if header["DATA"] else ""
    if data == "ascii":  # decimal text: keep what it says, not its float32 rounding
        dts = ["f8" if dt.startswith("f") else dt for dt in dts]
    dtype = np.dtype([(f"{nm}_{i}" if i else nm, "<" + dt)
                      for nm, dt, c in zip(names, dts, counts, strict=True)
                      for i in range(c)])
    try:
        if data == "ascii":
            text = raw[pos:].decode("ascii", "replace").split()
            if len(text) < n * len(dtype.names or ()):
                raise ValueError(f"{len(text)} values for {n} points")
            flat = np.array([float(x) for x in text[:n * len(dtype.names or ())]])
            table = flat.reshape(n, -1)
            rec = np.zeros(n, dtype=dtype)
            for k, nm in enumerate(dtype.names or ()):
                if dtype[nm].kind == "f":
                    rec[nm] = table[:, k]
                else:  # packed rgb written as an integer (or a float-typed integer)
                    rec[nm] = table[:, k].astype(np.int64).astype(dtype[nm])
        elif data == "binary":
            rec = np.frombuffer(raw, dtype=dtype, count=n, offset=pos)
        elif data == "binary_compressed":
            csize, usize = struct.unpack_from("<II", raw, pos)
            body = _lzf_decompress(np.frombuffer(raw, np.uint8, csize, pos + 8), usize)
            rec = np.zeros(n, dtype=dtype)
            off = 0
            for nm in dtype.names or ():  # field-major: all x, then all y ...
                sz = dtype[nm].itemsize * n
                rec[nm] = np.frombuffer(body[off:off + sz].tobytes(), dtype[nm], n)
                off += sz
        else:
            raise InputError(f"{p.name}: PCD DATA {data!r} is not ascii, binary or "
                             "binary_compressed")
    except InputError:
        raise
    except (ValueError, struct.error) as e:
        raise InputError(f"{p.name}: PCD data is truncated or damaged ({e}); export it "
                         "again") from None
    coord = "float64" if header["SIZE"][names.index("x")] == "8" else "float32"
    pts = np.stack([rec[a].astype(np.float64) for a in "xyz"], axis=1)
    nrm = (np.stack([rec[f"normal_{a}"].astype(np.float64) for a in "xyz"], axis=1)
           if all(f"normal_{a}" in names for a in "xyz") else None)
    cols = None
    colour = next((k for k in ("rgb", "rgba") if k in names), None)
    if colour is not None:
        packed = rec[colour]
        if header["TYPE"][names.index(colour)].upper() == "F":
            # PCL's default: the packed bytes stored as a float32 (ascii: its value, a
            # tiny or denormal number; read as f8 above) — the bits are the colour
            bits = np.ascontiguousarray(packed.astype(np.float32)).view(np.uint32)
        else:
            bits = packed.astype(np.uint32)
        cols = np.stack([(bits >> 16) & 255, (bits >> 8) & 255, bits & 255],
                        axis=1).astype(np.uint8)
    elif all(c in names for c in ("r", "g", "b")):
        cols = np.stack([rec[c] for c in "rgb"], axis=1).astype(np.uint8)
    return pts, cols, nrm, {"encoding": data, "coordinate_type": coord}


def _lzf_decompress(src: NDArray[np.uint8], size: int) -> NDArray[np.uint8]:
    """LibLZF decompression (PCD ``binary_compressed``), compiled with numba.

    Raises:
        ValueError: a damaged stream (a reference before the start, sizes that differ).
    """
    out = np.empty(size, np.uint8)
    n = _lzf_kernel()(src, out)
    if n != size:
        raise ValueError(f"LZF stream decompressed to {n} bytes, header says {size}")
    return out


def _lzf_kernel_py(src: NDArray[np.uint8], out: NDArray[np.uint8]) -> int:
    i = 0
    o = 0
    n_in = src.shape[0]
    n_out = out.shape[0]
    while i < n_in:
        ctrl = int(src[i])
        i += 1
        if ctrl < 32:  # a literal run of ctrl + 1 bytes
            ln = ctrl + 1
            if i + ln > n_in or o + ln > n_out:
                return -1
            out[o:o + ln] = src[i:i + ln]
            i += ln
            o += ln
        else:  # a back reference: length (ctrl >> 5) + 2, offset from 13 bits
            ln = ctrl >> 5
            if ln == 7:
                if i >= n_in:
                    return -1
                ln += int(src[i])
                i += 1
            if i >= n_in:
                return -1
            ref = o - ((ctrl & 31) << 8) - int(src[i]) - 1
            i += 1
            ln += 2
            if ref < 0 or o + ln > n_out:
                return -1
            for k in range(ln):  # byte by byte: the reference may overlap the output
                out[o + k] = out[ref + k]
            o += ln
    return o


@functools.cache
def _lzf_kernel() -> Callable[[NDArray[np.uint8], NDArray[np.uint8]], int]:
    """The LZF loop compiled on first use (a few MB of compressed cloud would take
    seconds in pure Python; compiling at import would slow every importer)."""
    from numba import njit

    return njit(nogil=True)(_lzf_kernel_py)  # type: ignore[no-any-return]


def load_intrinsics(path: str | Path) -> CameraIntrinsics:
    """Read camera intrinsics from the layouts other tools write.

    * Open3D ``PinholeCameraIntrinsic`` JSON: ``width``, ``height``, column-major
      ``intrinsic_matrix``;
    * a flat JSON with ``fx``, ``fy``, ``cx``/``ppx``, ``cy``/``ppy``, ``width``, ``height``
      (and ``coeffs``/``dist``): RealSense and many scripts' dumps;
    * ROS ``camera_info`` YAML (``image_width``, ``image_height``, ``camera_matrix.data``,
      ``distortion_coefficients.data``; or the message's ``width``, ``height``, ``K``/``k``,
      ``D``/``d``) and OpenCV calibration YAML/XML (``camera_matrix``, ``image_width``,
      ``distortion_coefficients``, as ``calibrateCamera`` samples write).

    Args:
        path: A ``.json``, ``.yaml``/``.yml`` or ``.xml`` file in one of the layouts above.

    Returns:
        The pinhole intrinsics (pixels) with the lens distortion when the file has one.

    Raises:
        InputError: unreadable file, or no layout above recognised (the message names the
            keys found and those expected).
    """
    p = Path(path)
    suf = p.suffix.lower()
    try:
        text = p.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"cannot read intrinsics from {p}: {e}") from None
    if suf == ".json":
        try:
            data = json.loads(text)
        except ValueError as e:
            raise InputError(f"{p.name}: not valid JSON ({e})") from None
        if not isinstance(data, dict):
            raise InputError(f"{p.name}: expected a JSON object with the intrinsics")
        if "intrinsic_matrix" in data:
            return load_intrinsics_json(p)
        return _intrinsics_from_keys(p, {k.lower(): v for k, v in data.items()})
    if suf in (".yaml", ".yml", ".xml"):
        return _intrinsics_from_filestorage(p, text)
    raise InputError(f"{p.name}: unsupported intrinsics file {suf or '(none)'!r}; use an "
                     "Open3D .json, a ROS camera_info .yaml or an OpenCV .yml/.xml")


def _intrinsics_from_keys(p: Path, d: dict[str, object]) -> CameraIntrinsics:
    """Intrinsics from a flat mapping (lower-case keys) of fx/fy/cx/cy or a K matrix."""

    def first(*names: str) -> object:
        return next((d[n] for n in names if n in d and d[n] is not None), None)

    w, h = first("width", "image_width"), first("height", "image_height")
    K = first("k", "camera_matrix")
    fx, fy = first("fx"), first("fy")
    cx, cy = first("cx", "ppx"), first("cy", "ppy")
    dist = first("d", "dist", "coeffs", "distortion_coefficients")
    try:
        if K is not None:
            Km = np.asarray(K, dtype=float).reshape(3, 3)
        elif None not in (fx, fy, cx, cy):
            Km = np.array([[float(fx), 0.0, float(cx)],  # type: ignore[arg-type]
                           [0.0, float(fy), float(cy)], [0.0, 0.0, 1.0]])  # type: ignore[arg-type]
        else:
            raise KeyError("fx, fy, cx, cy or a camera matrix")
        if w is None or h is None:
            raise KeyError("width and height")
        dv = None if dist is None else np.asarray(dist, dtype=float).ravel()
        return CameraIntrinsics.from_matrix(Km, int(w), int(h),  # type: ignore[call-overload]
                                            None if dv is None or not dv.size else dv)
    except KeyError as e:
        raise InputError(f"{p.name}: intrinsics need {e.args[0]}; found keys "
                         f"{sorted(d)}") from None
    except (TypeError, ValueError) as e:
        raise InputError(f"{p.name}: intrinsics values are not numbers of the right shape "
                         f"({e})") from None


def _intrinsics_from_filestorage(p: Path, text: str) -> CameraIntrinsics:
    """ROS camera_info / OpenCV calibration YAML (or XML) through ``cv2.FileStorage``
    (ROS files lack the ``%YAML:1.0`` line OpenCV needs: it is added)."""
    import cv2

    if p.suffix.lower() != ".xml" and not text.lstrip().startswith("%YAML"):
        text = "%YAML:1.0\n---\n" + text
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
        root = fs.root()
        if not root.isMap():
            raise InputError(f"{p.name}: expected a mapping of intrinsics keys")
        keys = list(root.keys())
        d: dict[str, object] = {}
        for k in keys:
            node = root.getNode(k)
            if node.isMap() and not node.getNode("data").empty():  # rows/cols/data
                data = node.getNode("data")
                d[k.lower()] = [data.at(i).real() for i in range(data.size())]
            elif node.isMap() and not node.getNode("dt").empty():  # an opencv-matrix
                m = node.mat()
                d[k.lower()] = None if m is None else m.ravel().tolist()
            elif node.isSeq():
                d[k.lower()] = [node.at(i).real() for i in range(node.size())]
            elif node.isReal() or node.isInt():
                d[k.lower()] = node.real()
    except cv2.error as e:
        raise InputError(f"{p.name}: not readable YAML/XML intrinsics ({str(e).strip()[:120]})"
                         ) from None
    return _intrinsics_from_keys(p, d)


#: depth beyond which a uint16 image read in millimetres is not a depth camera's (m)
_MAX_PLAUSIBLE_DEPTH_M = 12.0


def load_depth_image(path: str | Path, depth_scale: float | None = None
                     ) -> tuple[FloatArray, float]:
    """Read a depth image as metres.

    * 16-bit PNG/TIFF: raw units divided by ``depth_scale`` (default 1000: millimetres,
      Kinect/PrimeSense/most RealSense; 4000 for a RealSense L515's 0.25 mm units);
    * 32-bit float TIFF: metres (``depth_scale`` 1), or millimetres with ``depth_scale``
      1000;
    * OpenEXR, 8-bit or colour images are refused with what to export instead.

    A depth scale cannot be read from an image; a wrong one is caught only when the
    median depth becomes implausible (beyond 12 m, or below 5 cm): the error names the
    likely scale. Invalid pixels (0, NaN) are 0 in the result.

    Args:
        path: The depth image file.
        depth_scale: Raw units per metre (1000 for millimetres); None: 1000 for integer
            images, 1 for float images.

    Returns:
        ``(depth (H, W) float64 metres, the depth scale used)``.

    Raises:
        InputError: unreadable or unsupported image, or an implausible scale.
    """
    import cv2

    p = Path(path)
    if depth_scale is not None and not depth_scale > 0:
        raise InputError("depth_scale must be positive (1000 for millimetres, 4000 for a "
                         "RealSense L515, 1 for metres)")
    if not p.is_file():
        raise InputError(f"cannot read {p}: no such file")
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if img is None:
        if p.suffix.lower() == ".exr":
            raise InputError(f"{p.name}: OpenEXR is not readable by this OpenCV build; save "
                             "the depth as a 32-bit float TIFF (metres) or a 16-bit PNG "
                             "(millimetres)")
        raise InputError(f"{p.name}: not a readable image; a depth image is a 16-bit PNG "
                         "or a 16-bit/32-bit float TIFF")
    if img.ndim != 2:
        raise InputError(f"{p.name}: {img.shape[2]} channels — a colour image, not depth; "
                         "a depth image has one 16-bit or float channel")
    if img.dtype == np.uint8:
        raise InputError(f"{p.name}: 8-bit image — a depth visualisation, not depth; export "
                         "16-bit PNG (millimetres) or 32-bit float TIFF (metres)")
    floating = np.issubdtype(img.dtype, np.floating)
    scale = float(depth_scale) if depth_scale is not None else (1.0 if floating else 1000.0)
    depth = img.astype(np.float64) / scale
    depth[~np.isfinite(depth) | (depth < 0)] = 0.0
    valid = depth[depth > 0]
    if len(valid):
        med = float(np.median(valid))
        raw = med * scale
        if not 0.05 <= med <= _MAX_PLAUSIBLE_DEPTH_M:
            hint = next((f"; the depth is probably in units of 1/{s:g} m, pass "
                         f"depth_scale={s:g}" for s in (1.0, 1000.0, 4000.0, 10000.0)
                         if 0.3 <= raw / s <= 8.0), "")
            raise InputError(f"{p.name}: median depth {med:.3g} m at depth_scale {scale:g} "
                             f"is not a depth camera's{hint}")
    return depth, scale
