"""Ray-cast rendering of a simulated sensor's depth, body-index and colour images.

The room (floor with printed ArUco markers, walls) is static, so each sensor's
background depth/colour is ray-cast once (Open3D ``RaycastingScene``); per frame only the
pixels inside the projected bounding box of the bodies are cast against the body meshes
and composited, which keeps a 512×424 depth frame well above 30 frames/s on one core.

Floor markers are the real ``cv2.aruco`` DICT_4X4_50 images (with a white quiet zone)
textured onto the floor, so the calibration code detects them in the colour images.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import open3d as o3d
from numpy.typing import NDArray

from engine.errors import InputError
from engine.geometry import invert_transform, transform_points
from engine.sim.rig import FloorMarker, Rig, SimSensor

FloatArray = NDArray[np.float64]
BodyMesh = tuple[FloatArray, NDArray[np.int32], NDArray[np.int32]]

ARUCO_DICT = cv2.aruco.DICT_4X4_50
#: White border around each printed marker, as a fraction of the marker edge.
QUIET_ZONE = 0.25
_MARKER_PX = 120
_BODY_COLOURS = np.array([[60, 70, 140], [200, 60, 50], [60, 140, 70], [180, 150, 40],
                          [120, 60, 150], [40, 150, 160]], dtype=float)
_SKIN = np.array([215, 170, 140], dtype=float)


@dataclass
class SimFrame:
    """One simulated RGB-D frame of one sensor.

    Attributes:
        sensor_id: Sensor id.
        depth: ``(424, 512)`` uint16 depth in mm along the optical axis, 0 = no return
            (smaller for a renderer with ``image_scale`` < 1).
        body_index: ``(424, 512)`` uint8, 255 = no body, else the body's index.
        color: ``(H, W, 3)`` uint8 RGB or ``None`` when not rendered.
        K_depth: 3×3 depth intrinsics.
        K_color: 3×3 colour intrinsics at the rendered size (or ``None``).
        time_true: True capture time (s), if known.
        time_local: Sensor-clock capture time (s), if known.
        meta: Extra information (e.g. the skeleton row from :class:`SimWorld`).
    """

    sensor_id: str
    depth: NDArray[np.uint16]
    body_index: NDArray[np.uint8]
    color: NDArray[np.uint8] | None
    K_depth: FloatArray
    K_color: FloatArray | None
    time_true: float | None = None
    time_local: float | None = None
    meta: dict[str, Any] = field(default_factory=dict)


def _tensor(a: NDArray[Any]) -> Any:
    """numpy → Open3D tensor (shares memory; the stubs do not type this)."""
    return o3d.core.Tensor.from_numpy(np.ascontiguousarray(a))  # type: ignore[no-untyped-call]


def _pixel_rays(K: FloatArray, width: int, height: int, du: float = 0.0, dv: float = 0.0,
                dist: FloatArray | None = None) -> FloatArray:
    """Unit ray directions ``(H, W, 3)`` in the camera frame through pixel centres
    (integer coordinates, OpenCV convention) shifted by ``(du, dv)`` pixels; with OpenCV
    distortion ``dist`` the rays of the distorted image's pixels (a real lens)."""
    u, v = np.meshgrid(np.arange(width, dtype=float) + du, np.arange(height, dtype=float) + dv)
    if dist is not None and np.any(dist):
        # iterated to 1e-10 (OpenCV's default 5 iterations leave ~0.01 px at the border
        # of a strong lens): the rendered image must follow the model exactly
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)
        px = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
        n = cv2.undistortPoints(px, K, dist, None, None, None, crit).reshape(height, width, 2)
        d = np.concatenate([n, np.ones((height, width, 1))], axis=-1)
    else:
        d = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)],
                     axis=-1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def depth_to_points(depth: NDArray[Any], K: FloatArray, depth_scale: float = 1000.0
                    ) -> FloatArray:
    """Back-project a depth image to ``(N, 3)`` points in the camera frame (m).

    Args:
        depth: ``(H, W)`` depth along the optical axis (uint16 mm by default); 0 = none.
        K: 3×3 intrinsics.
        depth_scale: Depth units per metre.

    Returns:
        ``(N, 3)`` points of the pixels with depth, m (OpenCV camera frame).

    Raises:
        InputError: ``depth`` is not a 2-D image.
    """
    d = np.asarray(depth)
    if d.ndim != 2:
        raise InputError(f"depth must be a 2-D image, got shape {d.shape}")
    v, u = np.nonzero(d > 0)
    z = d[v, u].astype(float) / depth_scale
    return np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=1)


def _marker_texture(marker_id: int) -> NDArray[np.uint8]:
    """Marker image with its white quiet zone; black square spans the central part."""
    dictionary = cv2.aruco.getPredefinedDictionary(ARUCO_DICT)
    if marker_id >= 50:
        raise InputError(f"floor marker id {marker_id} is not in DICT_4X4_50 (ids 0–49)")
    img = cv2.aruco.generateImageMarker(dictionary, marker_id, _MARKER_PX, borderBits=1)
    pad = round(_MARKER_PX * QUIET_ZONE)
    return np.pad(img, pad, constant_values=255)


class _Room:
    """The static room geometry with material lookup."""

    def __init__(self, rig: Rig) -> None:
        r = rig.room
        x0, y0 = (float(v) for v in r.floor_min)
        x1, y1 = (float(v) for v in r.floor_max)
        h = float(r.wall_height)
        self.floor_v = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]],
                                dtype=np.float32)
        self.floor_f = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.uint32)
        wv: list[list[float]] = []
        wf: list[list[int]] = []
        corners = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
        for i in range(4):
            (ax, ay), (bx, by) = corners[i], corners[(i + 1) % 4]
            base = len(wv)
            wv += [[ax, ay, 0], [bx, by, 0], [bx, by, h], [ax, ay, h]]
            wf += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
        self.wall_v = np.array(wv, dtype=np.float32)
        self.wall_f = np.array(wf, dtype=np.uint32)
        self.markers: list[tuple[FloorMarker, FloatArray, NDArray[np.uint8]]] = [
            (m, invert_transform(m.T_world_marker), _marker_texture(m.id)) for m in rig.markers]

    def scene(self) -> tuple[o3d.t.geometry.RaycastingScene, int, int]:
        sc = o3d.t.geometry.RaycastingScene()
        fid = sc.add_triangles(_tensor(self.floor_v), _tensor(self.floor_f))
        wid = sc.add_triangles(_tensor(self.wall_v), _tensor(self.wall_f))
        return sc, fid, wid

    def floor_colour(self, p: FloatArray) -> FloatArray:
        """RGB of floor points ``(N, 3)``: grey tiles, markers with quiet zone.

        Args:
            p: ``(N, 3)`` world points on the floor, m.

        Returns:
            ``(N, 3)`` RGB, 0–255 floats.
        """
        # 0.5 m tiles with faint grout lines give the floor some texture
        fx, fy = np.mod(p[:, 0], 0.5), np.mod(p[:, 1], 0.5)
        grout = (np.minimum(fx, 0.5 - fx) < 0.008) | (np.minimum(fy, 0.5 - fy) < 0.008)
        tile = (np.floor(p[:, 0] / 0.5) + np.floor(p[:, 1] / 0.5)) % 2
        g = np.where(grout, 95.0, 140.0 + 12.0 * tile)
        col = np.repeat(g[:, None], 3, axis=1) * [1.0, 0.97, 0.9]
        if len(p) == 0:
            return col
        z_range = (float(np.nanmin(p[:, 2])), float(np.nanmax(p[:, 2])))
        for m, T_mw, tex in self.markers:
            half = m.size_m * (0.5 + QUIET_ZONE)
            # only points in the marker's world bounding box can be on it: transforming
            # every floor pixel once per marker was most of a renderer's construction
            box = _marker_box(m.T_world_marker, half, z_range)
            if box is None:
                idx = np.arange(len(p))
            else:
                lo, hi = box
                idx = np.flatnonzero(np.all((p >= lo) & (p <= hi), axis=1))
            if len(idx) == 0:
                continue
            q = transform_points(T_mw, p[idx])
            inside = (np.abs(q[:, 0]) <= half) & (np.abs(q[:, 1]) <= half)
            if not np.any(inside):
                continue
            n = tex.shape[0]
            # image column along marker +X, image row along marker −Y (see FloorMarker)
            col_px = np.clip(((q[inside, 0] + half) / (2 * half) * n).astype(int), 0, n - 1)
            row_px = np.clip(((half - q[inside, 1]) / (2 * half) * n).astype(int), 0, n - 1)
            col[idx[inside]] = tex[row_px, col_px][:, None].astype(float)
        return col


def _marker_box(T_world_marker: FloatArray, half: float, z_range: tuple[float, float]
                ) -> tuple[FloatArray, FloatArray] | None:
    """World axis-aligned box holding every point with world z in ``z_range`` whose
    marker-frame ``|x|, |y| <= half`` (the marker square's prism along its normal).

    Args:
        T_world_marker: The marker's pose.
        half: Half edge of the printed square (marker and quiet zone), m.
        z_range: ``(z_min, z_max)`` of the points to be tested, m (world).

    Returns:
        ``(lo, hi)`` corners, widened by 1 µm so rounding cannot drop a point on the
        square's edge; None when the normal is nearly horizontal (the prism is then not
        bounded by the z range: every point must be tested).
    """
    R, t = T_world_marker[:3, :3], T_world_marker[:3, 3]
    if abs(R[2, 2]) < 1e-3:
        return None
    # vertices of the prism cut by the planes z = z_min and z = z_max: the square's
    # corners slid along the normal until their world z reaches each plane
    corners = np.array([[sx * half, sy * half] for sx in (-1, 1) for sy in (-1, 1)])
    verts = []
    for z in z_range:
        s = (z - t[2] - corners @ R[2, :2]) / R[2, 2]
        local = np.column_stack([corners, s])
        verts.append(local @ R.T + t)
    v = np.concatenate(verts)
    return v.min(axis=0) - 1e-6, v.max(axis=0) + 1e-6


def _flying_pixels(z: FloatArray, rng: np.random.Generator, prob: float) -> FloatArray:
    """Time-of-flight "flying pixels": at depth edges (> 10 cm jump between neighbours)
    the farther pixel mixes both surfaces and reads an intermediate depth (Sarbolandi et
    al. 2015, CVIU 139:1; Fürsattel et al. 2016)."""
    out = z.copy()
    for axis in (0, 1):
        a = z[:-1, :] if axis == 0 else z[:, :-1]
        b = z[1:, :] if axis == 0 else z[:, 1:]
        with np.errstate(invalid="ignore"):
            edge = np.abs(b - a) > 0.10
        hit = edge & (rng.random(edge.shape) < prob)
        if not np.any(hit):
            continue
        near = np.minimum(a, b)[hit]
        far = np.maximum(a, b)[hit]
        mixed = near + rng.random(near.shape) * (far - near)
        ii, jj = np.nonzero(hit)
        far_is_b = (b > a)[hit]
        ii = ii + (far_is_b if axis == 0 else 0)
        jj = jj + (far_is_b if axis == 1 else 0)
        out[ii, jj] = mixed
    return out


def _lens(dist: Any, name: str) -> FloatArray | None:
    """OpenCV distortion coefficients as an array, None for none (or all zeros).

    Raises:
        InputError: not 4, 5, 8, 12 or 14 finite numbers.
    """
    d = None if dist is None else np.asarray(dist, dtype=float).ravel()
    if d is not None and (d.size not in (4, 5, 8, 12, 14) or not np.all(np.isfinite(d))):
        raise InputError(f"{name} must be 4, 5, 8, 12 or 14 finite OpenCV distortion "
                         f"coefficients, got {d.size}")
    return d if d is not None and np.any(d) else None


class SensorRenderer:
    """Renders one sensor's frames; the static room is cast once at construction.

    Args:
        sensor: The sensor.
        rig: The rig (room and markers).
        color_size: ``(width, height)`` of the colour image, or ``None`` for no colour.
        supersample: Samples per pixel axis for the static colour background.
        image_scale: Depth/body-index images at this fraction of the sensor's size, for
            live previews: ``(round(W·s), round(H·s))`` pixels with intrinsics ``K·s``
            (the geometry of an ``INTER_NEAREST`` downscale, which the live point cloud
            assumes), at a fraction of the cost. 1 (default): the sensor's images.
        color_dist: OpenCV distortion (k1, k2, p1, p2[, k3...]) of the colour lens, or
            None (default) for an ideal pinhole. Off by default: the simulated rig
            stands for sensors whose colour images are delivered rectified, and every
            recorded expectation (calibration accuracy, benches) is for that; tests of
            the lens path turn it on.
        depth_dist: the same for the depth lens (an Azure Kinect's depth images are not
            undistorted): each depth pixel measures along its distorted ray, depth
            still along the optical axis. The coefficients hold at any ``image_scale``.
            Off by default, as ``color_dist``.
    """

    def __init__(self, sensor: SimSensor, rig: Rig,
                 color_size: tuple[int, int] | None = (640, 360), supersample: int = 2,
                 image_scale: float = 1.0, color_dist: Any = None,
                 depth_dist: Any = None) -> None:
        self.sensor = sensor
        #: the colour lens's distortion (None: a pinhole)
        self.color_dist: FloatArray | None = _lens(color_dist, "color_dist")
        #: the depth lens's distortion (None: a pinhole)
        self.depth_dist: FloatArray | None = _lens(depth_dist, "depth_dist")
        self.model = sensor.model
        self.room = _Room(rig)
        m = self.model
        if not 0.0 < image_scale <= 1.0:
            raise InputError(f"image_scale must be in (0, 1], got {image_scale}")
        self.image_scale = image_scale
        self.K_depth = m.depth_intrinsics()
        dw, dh = m.depth_width, m.depth_height
        if image_scale != 1.0:
            self.K_depth = self.K_depth.copy()
            self.K_depth[:2, :3] *= image_scale
            dw, dh = max(1, round(dw * image_scale)), max(1, round(dh * image_scale))
        self.depth_shape = (dh, dw)
        scene, self._floor_id, self._wall_id = self.room.scene()
        self._rays_d = self._world_rays(sensor.T_world_sensor, self.K_depth, dw, dh,
                                        dist=self.depth_dist)
        self._dz_d = _pixel_rays(self.K_depth, dw, dh, dist=self.depth_dist)[..., 2]
        ans = scene.cast_rays(_tensor(self._rays_d))
        self._bg_t = ans["t_hit"].numpy().astype(float)  # distance along the unit ray
        self.color_size = color_size
        if color_size is not None:
            w, h = color_size
            if w < 16 or h < 16:
                raise InputError(f"color_size must be at least 16×16, got {color_size}")
            self.K_color = m.color_intrinsics(w, h)
            T_wc = sensor.T_world_color
            self._rays_c = self._world_rays(T_wc, self.K_color, w, h, dist=self.color_dist)
            ans = scene.cast_rays(_tensor(self._rays_c))
            self._bg_c_t = ans["t_hit"].numpy().astype(float)
            # the static background is anti-aliased by supersampling (cast once), so
            # marker corners are located with sub-pixel accuracy as in a real image
            acc = np.zeros((h, w, 3))
            offs = (np.arange(supersample) + 0.5) / supersample - 0.5
            for dv in offs:
                for du in offs:
                    rays = self._world_rays(T_wc, self.K_color, w, h, du, dv,
                                            self.color_dist)
                    acc += self._shade_static(rays, scene.cast_rays(_tensor(rays)))
            self._bg_color = np.round(acc / supersample**2).astype(np.uint8)

    @staticmethod
    def _world_rays(T_wc: FloatArray, K: FloatArray, w: int, h: int, du: float = 0.0,
                    dv: float = 0.0, dist: FloatArray | None = None) -> NDArray[np.float32]:
        d = _pixel_rays(K, w, h, du, dv, dist) @ T_wc[:3, :3].T
        o = np.broadcast_to(T_wc[:3, 3], d.shape)
        return np.concatenate([o, d], axis=-1).astype(np.float32)

    def _shade_static(self, rays: NDArray[np.float32], ans: dict[str, Any]) -> NDArray[np.uint8]:
        t = ans["t_hit"].numpy()
        gid = ans["geometry_ids"].numpy()
        H, W = t.shape
        col = np.full((H, W, 3), 70.0)  # no surface hit (e.g. above the walls): dark ceiling
        hit = np.isfinite(t)
        p = (rays[..., :3] + rays[..., 3:] * t[..., None]).astype(float)
        fl = hit & (gid == self._floor_id)
        col[fl] = self.room.floor_colour(p[fl])
        wl = hit & (gid == self._wall_id)
        col[wl] = np.array([205.0, 200.0, 185.0]) - 15.0 * (p[wl, 2:3] > 1.0)
        return np.clip(col, 0, 255).astype(np.uint8)

    @staticmethod
    def _bbox_pixels(T_cw: FloatArray, K: FloatArray, w: int, h: int,
                     verts: FloatArray, dist: FloatArray | None = None
                     ) -> tuple[slice, slice] | None:
        """Image window covering the projection of ``verts`` (None if not in view)."""
        q = transform_points(T_cw, verts)
        q = q[q[:, 2] > 0.05]
        if len(q) == 0:
            return None
        if dist is not None:
            uv, _ = cv2.projectPoints(q.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, dist)
            u, v = np.asarray(uv, dtype=float).reshape(-1, 2).T
        else:
            u = K[0, 0] * q[:, 0] / q[:, 2] + K[0, 2]
            v = K[1, 1] * q[:, 1] / q[:, 2] + K[1, 2]
        u0, u1 = int(max(np.floor(u.min()) - 1, 0)), int(min(np.ceil(u.max()) + 2, w))
        v0, v1 = int(max(np.floor(v.min()) - 1, 0)), int(min(np.ceil(v.max()) + 2, h))
        if u0 >= u1 or v0 >= v1:
            return None
        return slice(v0, v1), slice(u0, u1)

    def _cast_bodies(self, bodies: list[BodyMesh], rays: NDArray[np.float32],
                     window: tuple[slice, slice]) -> dict[str, NDArray[Any]]:
        sc = o3d.t.geometry.RaycastingScene()
        for V, F, _ in bodies:
            sc.add_triangles(_tensor(np.asarray(V, dtype=np.float32)),
                             _tensor(np.asarray(F, dtype=np.uint32)))
        sub = np.ascontiguousarray(rays[window])
        ans = sc.cast_rays(_tensor(sub))
        return {k: v.numpy() for k, v in ans.items()}

    def render(self, bodies: list[BodyMesh], rng: np.random.Generator | None = None,
               with_color: bool = True) -> SimFrame:
        """Render depth, body index and (optionally) colour with the given body meshes.

        Args:
            bodies: World-frame meshes ``(vertices, triangles, part_labels)``, one per body
                (index = position in the list).
            rng: Random generator for depth noise and dropouts (``None``: noise-free).
            with_color: Also render the colour image (if the renderer has a colour size).

        Returns:
            The frame: depth ``(H, W)`` uint16 mm along the optical axis (0 = no return),
            body index and colour.
        """
        m = self.model
        H, W = self.depth_shape
        t_hit = self._bg_t.copy()
        body = np.full((H, W), 255, dtype=np.uint8)
        all_v = [np.asarray(V, dtype=float) for V, _, _ in bodies if len(V)]
        if all_v:
            T_sw = self.sensor.T_sensor_world
            win = self._bbox_pixels(T_sw, self.K_depth, W, H, np.concatenate(all_v),
                                    self.depth_dist)
            if win is not None:
                ans = self._cast_bodies(bodies, self._rays_d, win)
                tb = ans["t_hit"]
                closer = tb < t_hit[win]
                t_hit[win] = np.where(closer, tb, t_hit[win])
                gid = ans["geometry_ids"].astype(np.int64)
                body[win] = np.where(closer, np.clip(gid, 0, 254), 255).astype(np.uint8)
        z = t_hit * self._dz_d
        valid = np.isfinite(z) & (z >= m.range_min_m) & (t_hit <= m.range_max_m)
        if rng is not None:
            z = z + rng.standard_normal(z.shape) * m.depth_noise_sd(np.where(valid, z, 0.0))
            valid &= rng.random(z.shape) >= m.depth_dropout
            if m.flying_pixel_prob > 0:
                z = _flying_pixels(np.where(valid, z, np.nan), rng, m.flying_pixel_prob)
                valid &= np.isfinite(z)
        depth = np.where(valid, np.round(np.where(valid, z, 0.0) * 1000.0), 0).astype(np.uint16)
        body[~valid] = 255
        color = None
        K_color = None
        if with_color and self.color_size is not None:
            color = self._render_color(bodies)
            K_color = self.K_color
        return SimFrame(sensor_id=self.sensor.id, depth=depth, body_index=body, color=color,
                        K_depth=self.K_depth, K_color=K_color)

    def _render_color(self, bodies: list[BodyMesh]) -> NDArray[np.uint8]:
        assert self.color_size is not None
        w, h = self.color_size
        img = self._bg_color.copy()
        all_v = [np.asarray(V, dtype=float) for V, _, _ in bodies if len(V)]
        if not all_v:
            return img
        T_cw = invert_transform(self.sensor.T_world_color)
        win = self._bbox_pixels(T_cw, self.K_color, w, h, np.concatenate(all_v),
                                self.color_dist)
        if win is None:
            return img
        ans = self._cast_bodies(bodies, self._rays_c, win)
        tb = ans["t_hit"]
        closer = tb < self._bg_c_t[win]
        if not np.any(closer):
            return img
        gid = ans["geometry_ids"].astype(np.int64)
        prim = ans["primitive_ids"].astype(np.int64)
        normals = ans["primitive_normals"]
        d = self._rays_c[win][..., 3:]
        shade = np.abs(np.sum(normals * d, axis=-1))
        col = np.zeros((*tb.shape, 3))
        for b, (_, F, labels) in enumerate(bodies):
            sel = closer & (gid == b)
            if not np.any(sel):
                continue
            lab = np.asarray(labels)[np.clip(prim[sel], 0, len(F) - 1)]
            # capsule order of Walker.capsules: skin on neck/head/hands, dark trousers
            # on pelvis/legs, near-black shoes
            base = np.broadcast_to(_BODY_COLOURS[b % len(_BODY_COLOURS)], (len(lab), 3)).copy()
            base[np.isin(lab, [2, 3, 9, 15])] = _SKIN
            base[np.isin(lab, [0, 4, 5, 10, 11])] *= 0.5
            base[np.isin(lab, [6, 12])] = 35.0
            col[sel] = base * (0.35 + 0.65 * shade[sel])[:, None]
        sub = img[win]
        sub[closer] = np.clip(col[closer], 0, 255).astype(np.uint8)
        img[win] = sub
        return img


def render_frame(
    sensor: SimSensor,
    rig: Rig,
    body_meshes_world: list[BodyMesh],
    *,
    color_size: tuple[int, int] | None = (640, 360),
    rng: np.random.Generator | None = None,
) -> SimFrame:
    """Render one frame (convenience; build a :class:`SensorRenderer` to render many).

    Args:
        sensor: The simulated sensor.
        rig: Its rig (room, floor markers).
        body_meshes_world: World-frame body meshes, one per body.
        color_size: Colour image size ``(width, height)``; None: no colour image.
        rng: Random generator for depth noise; None: noise-free.

    Returns:
        The frame (depth as uint16 mm along the optical axis, 0 = no return; body
        index; colour).
    """
    return SensorRenderer(sensor, rig, color_size).render(body_meshes_world, rng,
                                                          with_color=color_size is not None)
