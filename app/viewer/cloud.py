"""Merged live point cloud: unproject depth images, move them to the world, voxel-merge.

The live view needs the clouds of all sensors several times per second on a 2-core
machine, so the whole pipeline (per-pixel unprojection with the sensor's intrinsics,
``T_world_sensor`` transform, voxel averaging) is one compiled pass per depth image into a
dense voxel grid covering the points' bounding box. Pixel rays are precomputed per
intrinsics and lens (:func:`engine.pointcloud.pixel_ray_table`: an Azure Kinect's depth
lens bends the rays by centimetres at the image border), so a frame costs one multiply-add
per pixel plus the voxel scatter, with or without a lens. The result
is float32 points and uint8 colours, ready for viser (``precision="float32"``; float16
loses millimetres a few metres from the origin).

``bench/live.py`` measures this against Open3D's ``create_from_depth_image`` +
``transform`` + ``voxel_down_sample`` doing the same work.
"""

from __future__ import annotations

import functools
import threading
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from engine.errors import InputError
from engine.pointcloud import (
    JUMP_EDGE_ANGLE_DEG,
    CameraIntrinsics,
    jump_edge_pixels,
    undistort_normalised,
)

MAX_VOXELS = 64_000_000  # dense-grid cells (int32 index): 256 MB at most, far above a lab


@dataclass(frozen=True)
class DepthView:
    """One depth image to merge.

    Attributes:
        depth_mm: ``(H, W)`` uint16 depth in millimetres (0 = no measurement).
        K: 3×3 intrinsics of *this* image (scale them when the image was resized).
        T_world_sensor: 4×4 pose of the depth camera (OpenCV frame).
        color: RGB colour of this sensor's points.
        highlight: optional ``(H, W)`` bool mask of pixels drawn in ``highlight_color``
            (the tracked body).
        dist: OpenCV distortion coefficients of the depth lens (k1, k2, p1, p2[, k3...]);
            ``()``: a pinhole (sensors that deliver undistorted depth, older nodes). They
            do not change when the image is resized (only ``K`` does).
    """

    depth_mm: NDArray[np.uint16]
    K: NDArray[np.float64]
    T_world_sensor: NDArray[np.float64]
    color: tuple[int, int, int] = (200, 200, 200)
    highlight: NDArray[np.bool_] | None = None
    dist: tuple[float, ...] = ()


#: bytes of ray tables kept (LRU): a node cannot grow the cache by announcing lenses or
#: sending frames of many sizes; the largest image a node may send (hub
#: ``MAX_IMAGE_PIXELS``, 4096²) makes a 134 MB table, so one always fits
MAX_RAYS_CACHE_BYTES = 256 * 2**20
_rays_cache: OrderedDict[tuple[int, int, bytes, tuple[float, ...]], NDArray[np.float32]] = \
    OrderedDict()
_rays_lock = threading.Lock()


def pixel_rays(K: NDArray[np.float64], width: int, height: int,
               dist: tuple[float, ...] = ()) -> NDArray[np.float32]:
    """``(H, W, 2)`` normalised undistorted rays ``(x/z, y/z)`` of every pixel (cached by
    intrinsics, lens and image size: the live view's frame size follows the node's scale).

    Without a lens: ``((u - cx)/fx, (v - cy)/fy)``. Pixels outside a lens's valid field
    are NaN (skipped). :func:`engine.pointcloud.pixel_ray_table`'s rays, kept in this
    module's cache (at most :data:`MAX_RAYS_CACHE_BYTES`), not the engine's.

    Raises:
        InputError: not a 3×3 matrix with positive focal lengths, or distortion that is
            not OpenCV's.
    """
    K = np.asarray(K, dtype=np.float64)
    d = tuple(float(x) for x in dist) if any(dist) else ()
    key = (width, height, K.tobytes(), d)
    with _rays_lock:
        r = _rays_cache.get(key)
        if r is not None:
            _rays_cache.move_to_end(key)
    if r is None:
        if K.shape != (3, 3) or not (K[0, 0] > 0 and K[1, 1] > 0):
            raise InputError("depth intrinsics must be a 3×3 matrix with positive focal lengths")
        intr = CameraIntrinsics.from_matrix(K, width, height, d or None)
        # pixel_ray_table's rays, computed here: its own cache holds 16 float64 tables
        # whatever their size (4.3 GB at 4096² frames), this one is bounded in bytes
        u, v = np.meshgrid(np.arange(width, dtype=np.float64),
                           np.arange(height, dtype=np.float64))
        rays = undistort_normalised(np.stack([u.ravel(), v.ravel()], axis=1), intr)
        r = np.ascontiguousarray(rays.reshape(height, width, 2), dtype=np.float32)
        with _rays_lock:
            while _rays_cache and (sum(t.nbytes for t in _rays_cache.values()) + r.nbytes
                                   > MAX_RAYS_CACHE_BYTES):
                _rays_cache.popitem(last=False)  # the least recently used
            _rays_cache[key] = r
    return r


def calibrated_depth_lens(cameras: Mapping[str, Any], node_id: str, K: Any,
                          size: tuple[int, int]) -> tuple[float, ...] | None:
    """A node's depth lens as the active calibration recorded it, for the live cloud.

    The lens reaches the server only with the calibration capture (``calib`` header
    ``depth_dist``; the node's hello has no lens field, so older servers accept newer
    nodes) and is kept in the calibration's ``meta["cameras"]``. It is used only while
    the node still reports the camera it was calibrated with: the recorded depth ``K``,
    scaled to the node's depth size, must match its ``K`` (focal lengths within 0.1 %,
    principal point within 1 px).

    Args:
        cameras: ``CalibrationResult.meta["cameras"]`` (``{node: {"depth": {"size", "K",
            "dist"}}}``).
        node_id: The node.
        K: The 3×3 depth intrinsics the node reports (at ``size``), or None.
        size: ``(width, height)`` of the node's depth images for ``K``.

    Returns:
        The OpenCV coefficients, ``()`` for a calibrated pinhole (or none recorded:
        calibrations before lenses were kept, older nodes), None when the recorded camera
        is not the node's or its lens is not one the ray table models (a tilted sensor,
        a malformed record): the caller keeps a pinhole and says so.
    """
    cam = cameras.get(node_id) if isinstance(cameras, Mapping) else None
    depth = cam.get("depth") if isinstance(cam, Mapping) else None
    if not isinstance(depth, Mapping) or not depth.get("dist"):
        return ()
    try:
        Kc = np.asarray(depth["K"], dtype=float).reshape(3, 3)
        cw, ch = (float(x) for x in depth["size"])
        dist = tuple(float(x) for x in depth["dist"])
        Kn = np.asarray(K, dtype=float).reshape(3, 3)
    except (KeyError, TypeError, ValueError):
        return None
    if not any(dist):
        return ()
    if (len(dist) not in (4, 5, 8, 12, 14) or not np.isfinite(dist).all()
            or (len(dist) == 14 and any(dist[12:]))):  # not a lens the ray table models
        return None
    sx, sy = size[0] / cw, size[1] / ch
    f_ok = (abs(Kc[0, 0] * sx - Kn[0, 0]) <= 1e-3 * Kn[0, 0]
            and abs(Kc[1, 1] * sy - Kn[1, 1]) <= 1e-3 * Kn[1, 1])
    c_ok = abs(Kc[0, 2] * sx - Kn[0, 2]) <= 1.0 and abs(Kc[1, 2] * sy - Kn[1, 2]) <= 1.0
    return dist if f_ok and c_ok else None


def scale_intrinsics(K: NDArray[np.float64], scale: float) -> NDArray[np.float64]:
    """Intrinsics of a depth image the node downscaled by ``scale``.

    Nodes resize depth with OpenCV's ``INTER_NEAREST``, which gives pixel ``u'`` the source
    pixel ``floor(u' / scale)``: source coordinates are ``u' / scale``, so focal lengths
    and principal point scale alike (no half-pixel shift, unlike area averaging).
    """
    K2 = np.array(K, dtype=np.float64)
    K2[:2, :3] *= scale
    return K2


def _bounds(depth: NDArray[np.uint16], rays: NDArray[np.float32], T: NDArray[np.float64],
            zmin: float, zmax: float, out: NDArray[np.float64]) -> int:  # pragma: no cover
    n = 0
    H, W = depth.shape
    for i in range(H):
        for j in range(W):
            d = depth[i, j]
            if d == 0:
                continue
            z = d * 0.001
            if z < zmin or z > zmax:
                continue
            rx = rays[i, j, 0]
            if rx != rx:  # NaN: no ray inside the lens's valid field
                continue
            x = rx * z
            y = rays[i, j, 1] * z
            for k in range(3):
                p = T[k, 0] * x + T[k, 1] * y + T[k, 2] * z + T[k, 3]
                if p < out[k]:
                    out[k] = p
                if p > out[3 + k]:
                    out[3 + k] = p
            n += 1
    return n


def _scatter(depth: NDArray[np.uint16], rays: NDArray[np.float32], T: NDArray[np.float64],
             zmin: float, zmax: float, lo: NDArray[np.float64], inv_voxel: float,
             dims: NDArray[np.int64], index: NDArray[np.int32], sums: NDArray[np.float64],
             cols: NDArray[np.float64], counts: NDArray[np.int64], n_used: int,
             rgb: NDArray[np.float64], hl: NDArray[np.bool_], use_hl: bool,
             hl_rgb: NDArray[np.float64]) -> int:  # pragma: no cover
    H, W = depth.shape
    ny, nz = dims[1], dims[2]
    for i in range(H):
        for j in range(W):
            d = depth[i, j]
            if d == 0:
                continue
            z = d * 0.001
            if z < zmin or z > zmax:
                continue
            rx = rays[i, j, 0]
            if rx != rx:  # NaN: no ray inside the lens's valid field
                continue
            x = rx * z
            y = rays[i, j, 1] * z
            px = T[0, 0] * x + T[0, 1] * y + T[0, 2] * z + T[0, 3]
            py = T[1, 0] * x + T[1, 1] * y + T[1, 2] * z + T[1, 3]
            pz = T[2, 0] * x + T[2, 1] * y + T[2, 2] * z + T[2, 3]
            ix = int((px - lo[0]) * inv_voxel)
            iy = int((py - lo[1]) * inv_voxel)
            iz = int((pz - lo[2]) * inv_voxel)
            # rounding can put the farthest point one cell out: clamp
            ix = min(ix, dims[0] - 1)
            iy = min(iy, ny - 1)
            iz = min(iz, nz - 1)
            cell = (ix * ny + iy) * nz + iz
            slot = index[cell]
            if slot < 0:
                slot = n_used
                index[cell] = slot
                n_used += 1
            sums[slot, 0] += px
            sums[slot, 1] += py
            sums[slot, 2] += pz
            c = hl_rgb if (use_hl and hl[i, j]) else rgb
            cols[slot, 0] += c[0]
            cols[slot, 1] += c[1]
            cols[slot, 2] += c[2]
            counts[slot] += 1
    return n_used


@functools.cache
def _kernels() -> tuple[Any, Any]:
    """:func:`_bounds` and :func:`_scatter` compiled (numba, cached on disk); numba is
    loaded by the first cloud, not at the server's start (the API imports this module)."""
    import numba

    jit = numba.njit(cache=True, nogil=True)
    return jit(_bounds), jit(_scatter)


def merge_depth_views(views: Sequence[DepthView], voxel_m: float = 0.03,
                      z_range_m: tuple[float, float] = (0.3, 8.0),
                      highlight_color: tuple[int, int, int] = (255, 0, 200),
                      jump_edge_deg: float | None = JUMP_EDGE_ANGLE_DEG,
                      ) -> tuple[NDArray[np.float32], NDArray[np.uint8]]:
    """Unproject, transform and voxel-average several depth images into one world cloud.

    Each occupied voxel yields one point: the mean of its points, coloured by the mean
    colour of its points (sensor colour, or the highlight colour for masked pixels). A view
    with a lens (``DepthView.dist``) is unprojected along its pixels' undistorted rays.

    Args:
        views: depth images with intrinsics and poses.
        voxel_m: voxel edge length (m).
        z_range_m: usable depth range along the optical axis (m).
        highlight_color: colour of highlighted (body) pixels.
        jump_edge_deg: pixels behind a depth edge are dropped
            (:func:`engine.pointcloud.jump_edge_pixels` with this angle): the flying
            pixels of a time-of-flight sensor would float in the air behind a walker,
            on the floor a clinician checks. None: every pixel is kept.

    Returns:
        ``(points (N, 3) float32 world metres, colours (N, 3) uint8)``.

    Raises:
        InputError: bad voxel size, intrinsics or pose, or a cloud spanning too many voxels.
    """
    if not voxel_m > 0:
        raise InputError("voxel size must be > 0 m")
    bounds_kernel, scatter_kernel = _kernels()
    prepared = []
    bounds = np.array([np.inf] * 3 + [-np.inf] * 3)
    total = 0
    for v in views:
        depth = np.ascontiguousarray(v.depth_mm, dtype=np.uint16)
        if depth.ndim != 2:
            raise InputError("a depth image must be 2-D (H, W) uint16 millimetres")
        T = np.ascontiguousarray(v.T_world_sensor, dtype=np.float64)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise InputError("T_world_sensor must be a finite 4×4 matrix")
        rays = pixel_rays(v.K, depth.shape[1], depth.shape[0], v.dist)
        if jump_edge_deg is not None:
            depth = np.where(jump_edge_pixels(depth * np.float32(0.001), rays, jump_edge_deg),
                             np.uint16(0), depth)
        total += bounds_kernel(depth, rays, T, z_range_m[0], z_range_m[1], bounds)
        prepared.append((depth, rays, T, v))
    if total == 0:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8)
    lo = bounds[:3]
    dims = (np.floor((bounds[3:] - lo) / voxel_m).astype(np.int64) + 1)
    if int(np.prod(dims)) > MAX_VOXELS:
        raise InputError(f"the cloud spans {dims.tolist()} voxels of {voxel_m} m; use a larger "
                         "voxel or a shorter depth range")
    index = np.full(int(np.prod(dims)), -1, np.int32)
    sums = np.zeros((total, 3))
    cols = np.zeros((total, 3))
    counts = np.zeros(total, np.int64)
    n = 0
    hl_rgb = np.asarray(highlight_color, np.float64)
    no_hl = np.zeros((1, 1), np.bool_)
    for depth, rays, T, v in prepared:
        hl = no_hl if v.highlight is None else np.ascontiguousarray(v.highlight, np.bool_)
        if v.highlight is not None and hl.shape != depth.shape:
            raise InputError("the highlight mask must have the depth image's shape")
        n = scatter_kernel(depth, rays, T, z_range_m[0], z_range_m[1], lo, 1.0 / voxel_m, dims,
                     index, sums, cols, counts, n, np.asarray(v.color, np.float64), hl,
                     v.highlight is not None, hl_rgb)
    c = counts[:n, None]
    pts = (sums[:n] / c).astype(np.float32)
    rgb = np.clip(cols[:n] / c + 0.5, 0, 255).astype(np.uint8)
    return pts, rgb


def serialise_cloud(points: NDArray[np.float32], colors: NDArray[np.uint8]) -> bytes:
    """Wire form of a cloud: uint32 count, float32 xyz, then uint8 rgb (little-endian)."""
    n = np.array([len(points)], "<u4").tobytes()
    return n + np.ascontiguousarray(points, "<f4").tobytes() + np.ascontiguousarray(
        colors, np.uint8).tobytes()
