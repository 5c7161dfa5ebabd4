"""3D marker corners from depth registered to colour, averaged over frames.

For each marker detected in a colour image, the depth pixels whose 3D points project inside
the marker quad are collected (depth → depth-camera points → colour camera → pixels), a
plane is fitted to them (RANSAC, then least squares on the inliers), and the four sub-pixel
corner rays of the colour camera are intersected with that plane. This is far more
accurate than reading the depth at the corner pixels: a corner lies on an edge where depth
pixels mix foreground and background, and the plane uses hundreds of pixels at once.

Each corner also gets a 3×3 covariance (the sensor frame) from two sources: the sub-pixel
corner noise moved onto the plane (grows with distance and with grazing view angles), and
the plane-height uncertainty of the fit at that corner (shrinks with more pixels and more
frames). The joint optimisation (:mod:`engine.calibration.posegraph`) weights every corner
by it.

Observations over N frames (default 30) are averaged; an observation that cannot be
trusted is kept with ``accepted=False`` and a ``reason`` a person can act on.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.calibration.detect import (
    DetectionSet,
    MarkerDetection,
    detect_markers,
    make_detector,
)
from engine.calibration.markers import DEFAULT_DICTIONARY
from engine.errors import InputError
from engine.geometry import invert_transform, transform_points
from engine.pointcloud import CameraIntrinsics, as_intrinsics

FloatArray = NDArray[np.float64]

#: Default number of frames averaged per observation.
DEFAULT_FRAMES = 30


@dataclass(frozen=True)
class CornerParams:
    """Thresholds of the 3D-corner step.

    Attributes:
        min_points: Fewest depth points inside a marker for a plane fit.
        max_plane_rms_m: Largest RMS distance of the inliers to the plane.
        min_inlier_fraction: Smallest share of points near the plane (occlusion guard).
        ransac_threshold_m: Inlier distance for RANSAC.
        ransac_iterations: Plane hypotheses tried.
        min_frames: Fewest frames an observation needs; ``None`` = max(2, 30 % of frames).
        corner_sigma_px: Sub-pixel corner noise floor (1σ, pixels) used for weights.
        corner_sigma_k: Corner noise growing for small markers: σ = floor + k / √area_px
            (the pattern fit has fewer edge pixels on a small or foreshortened marker).
        min_ray_angle_deg: Smallest angle between a corner ray and the marker plane.
        shrink: The quad is shrunk by this factor about its centre before selecting depth
            points (avoids mixed pixels at the marker's outline).
    """

    min_points: int = 30
    max_plane_rms_m: float = 0.012
    min_inlier_fraction: float = 0.6
    ransac_threshold_m: float = 0.015
    ransac_iterations: int = 60
    min_frames: int | None = None
    corner_sigma_px: float = 0.02
    corner_sigma_k: float = 4.0
    min_ray_angle_deg: float = 4.0
    shrink: float = 0.85


@dataclass
class FrameCorners:
    """Corners of one marker in one frame (sensor = depth-camera frame).

    Attributes:
        corners: (4, 3) corner positions (m).
        cov: (4, 3, 3) covariances from pixel noise (not reduced by averaging frames).
        cov_plane: (4, 3, 3) covariances from the plane fit (independent per frame).
        n_points: Depth points used by the plane (inliers).
        plane_rms_m: Inlier RMS distance to the plane.
    """

    corners: FloatArray
    cov: FloatArray
    cov_plane: FloatArray
    n_points: int
    plane_rms_m: float


@dataclass
class Observation:
    """One sensor's view of one marker, averaged over frames.

    Attributes:
        sensor_id: Sensor id.
        marker_id: Marker id.
        accepted: Whether the observation is used by the calibration.
        reason: Why it was rejected ("" when accepted).
        corners: (4, 3) corners in the sensor (depth camera) frame, OpenCV corner order;
            NaN when no frame gave corners.
        cov: (4, 3, 3) covariance of each averaged corner (m²).
        n_frames: Frames that produced corners.
        n_frames_seen: Frames in which the marker was detected in colour.
        n_points: Mean depth points per plane fit.
        plane_rms_m: Mean plane-fit RMS (m).
        distance_m: Distance from the sensor to the marker centre (m).
        corners_px: (4, 2) colour-image corners of the first detection.
        measured_edge_m: Mean edge length of the 3D corners (m), set when the graph step
            checks it against the given size; NaN before.
        given_edge_m: The size it was checked against (m); NaN before.
    """

    sensor_id: str
    marker_id: int
    accepted: bool
    reason: str = ""
    corners: FloatArray = field(default_factory=lambda: np.full((4, 3), np.nan))
    cov: FloatArray = field(default_factory=lambda: np.tile(np.eye(3), (4, 1, 1)))
    n_frames: int = 0
    n_frames_seen: int = 0
    n_points: float = 0.0
    plane_rms_m: float = float("nan")
    distance_m: float = float("nan")
    corners_px: FloatArray = field(default_factory=lambda: np.full((4, 2), np.nan))
    measured_edge_m: float = float("nan")
    given_edge_m: float = float("nan")

    def to_dict(self) -> dict[str, object]:
        """JSON-friendly summary (no corners; distances rounded).

        Returns:
            Sensor, marker, acceptance and its reason, frame counts, points per frame, plane
            RMS (mm) and distance (m); None where a value is not finite.
        """
        return {
            "sensor": self.sensor_id, "marker": self.marker_id, "accepted": self.accepted,
            "reason": self.reason, "frames": self.n_frames, "frames_seen": self.n_frames_seen,
            "points": round(self.n_points, 1),
            "plane_rms_mm": None if not np.isfinite(self.plane_rms_m)
            else round(self.plane_rms_m * 1000, 2),
            "distance_m": None if not np.isfinite(self.distance_m)
            else round(self.distance_m, 3),
        }


@dataclass
class SensorFrames:
    """Synchronised colour + depth frames of one sensor and its camera model.

    Attributes:
        sensor_id: Sensor id.
        colors: Colour images (H, W, 3) uint8 (RGB or BGR).
        depths: Depth images (h, w) in raw units (``depth_scale`` per metre).
        depth_intrinsics: Depth camera intrinsics (:class:`CameraIntrinsics` or 3×3 K
            with the image size taken from the first depth frame).
        color_intrinsics: Colour camera intrinsics (same forms; distortion allowed).
        T_depth_color: 4×4 colour → depth camera transform (factory extrinsics).
        depth_scale: Raw depth units per metre (1000 for millimetres).
    """

    sensor_id: str
    colors: Sequence[NDArray[np.uint8]]
    depths: Sequence[NDArray[np.generic]] | None
    depth_intrinsics: CameraIntrinsics | FloatArray
    color_intrinsics: CameraIntrinsics | FloatArray
    T_depth_color: FloatArray = field(default_factory=lambda: np.eye(4))
    depth_scale: float = 1000.0


def _intr(obj: CameraIntrinsics | ArrayLike, shape: tuple[int, ...]) -> CameraIntrinsics:
    if isinstance(obj, CameraIntrinsics):
        return obj
    arr = np.asarray(obj, dtype=float) if not hasattr(obj, "fx") else None
    if arr is not None and arr.shape == (3, 3):
        return CameraIntrinsics.from_matrix(arr, shape[1], shape[0])
    return as_intrinsics(obj)


def fit_plane(
    points: FloatArray, params: CornerParams, rng: np.random.Generator
) -> tuple[FloatArray, float, NDArray[np.bool_]] | None:
    """Robust plane through ``points`` (N, 3): RANSAC, then least squares on inliers.

    Args:
        points: ``(N, 3)`` points, m.
        params: Thresholds (inlier distance, iterations).
        rng: Random generator of the RANSAC samples.

    Returns:
        ``(plane (4,) = (n, d) with n·x = d and |n| = 1, inlier RMS, inlier mask)`` or None
        when no plane has three points.
    """
    n_pts = points.shape[0]
    if n_pts < 3:
        return None
    k = params.ransac_iterations
    idx = rng.integers(0, n_pts, size=(k, 3))
    a, b, c = points[idx[:, 0]], points[idx[:, 1]], points[idx[:, 2]]
    nrm = np.cross(b - a, c - a)
    ln = np.linalg.norm(nrm, axis=1)
    good = ln > 1e-9
    if not np.any(good):
        return None
    nrm = nrm[good] / ln[good, None]
    d = np.sum(nrm * a[good], axis=1)
    dist = np.abs(points @ nrm.T - d[None, :])  # (N, k)
    counts = (dist < params.ransac_threshold_m).sum(axis=0)
    best = int(np.argmax(counts))
    inl = dist[:, best] < params.ransac_threshold_m
    plane = np.append(nrm[best], d[best])
    for _ in range(2):  # least-squares refinement on the inliers, then re-select them
        if inl.sum() < 3:
            return None
        p = points[inl]
        cen = p.mean(axis=0)
        _, _, vt = np.linalg.svd(p - cen, full_matrices=False)
        n = vt[2]
        plane = np.append(n, n @ cen)
        inl = np.abs(points @ n - plane[3]) < params.ransac_threshold_m
    res = points[inl] @ plane[:3] - plane[3]
    return plane, float(np.sqrt(np.mean(res * res))) if res.size else float("inf"), inl


def _inside_quad(uv: FloatArray, quad: FloatArray) -> NDArray[np.bool_]:
    """Points (N, 2) inside the convex quad (4, 2) of either winding."""
    s = np.empty((uv.shape[0], 4))
    for i in range(4):
        a, b = quad[i], quad[(i + 1) % 4]
        s[:, i] = (b[0] - a[0]) * (uv[:, 1] - a[1]) - (b[1] - a[1]) * (uv[:, 0] - a[0])
    return np.all(s >= 0, axis=1) | np.all(s <= 0, axis=1)


_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)


def detect_with_lens(image: ArrayLike, intrinsics: CameraIntrinsics,
                     dictionary: str = DEFAULT_DICTIONARY,
                     detector: cv2.aruco.ArucoDetector | None = None) -> DetectionSet:
    """Markers in ``image`` as the calibration finds them: with the camera's lens.

    A lens with distortion bends the markers' edges, which the detector's quads and the
    pattern fit take straight: the markers are then found in the undistorted image and
    their corners mapped back to the image's own pixels
    (:func:`engine.calibration.detect.detect_markers` with ``K`` and ``dist``), which
    :func:`corner_rays` undistorts. Without distortion: the plain detection.

    Args:
        image: The colour (or grey) image, uint8.
        intrinsics: The colour camera's intrinsics and lens.
        dictionary: Marker dictionary name.
        detector: A detector to reuse (:func:`engine.calibration.detect.make_detector`).

    Returns:
        The markers found, corners in the image's own pixels.
    """
    if intrinsics.dist and np.any(intrinsics.dist_array != 0):
        return detect_markers(image, dictionary, detector=detector, K=intrinsics.K,
                              dist=intrinsics.dist_array)
    return detect_markers(image, dictionary, detector=detector)


def corner_rays(px: ArrayLike, intrinsics: CameraIntrinsics) -> FloatArray:
    """Rays with z = 1 (camera frame) through image pixels of a camera with a lens.

    Args:
        px: ``(N, 2)`` pixel coordinates ``(u, v)``.
        intrinsics: The camera's intrinsics; its distortion is removed.

    Returns:
        ``(N, 3)`` rays ``(x/z, y/z, 1)``.
    """
    return _undistorted_rays(np.asarray(px, dtype=np.float64).reshape(-1, 2), intrinsics)


def _undistorted_rays(px: FloatArray, intr: CameraIntrinsics) -> FloatArray:
    """Rays (N, 3) with z = 1 through pixels (N, 2) of a (possibly distorted) camera."""
    if intr.dist and np.any(np.asarray(intr.dist) != 0):
        # iterated to convergence: OpenCV's default 5 iterations leave 0.1 px at the
        # border of a strong barrel lens (k1 = -0.3), 1 mm on a marker corner at 5 m
        n = cv2.undistortPoints(px.reshape(-1, 1, 2).astype(np.float64), intr.K,
                                intr.dist_array, None, None, None,
                                _UNDISTORT_CRITERIA).reshape(-1, 2)
    else:
        n = np.stack([(px[:, 0] - intr.cx) / intr.fx, (px[:, 1] - intr.cy) / intr.fy], axis=1)
    return np.column_stack([n, np.ones(len(n))])


class FrameCornerEstimator:
    """Computes 3D corners of the markers detected in one RGB-D frame.

    Args:
        depth_intrinsics: Depth camera intrinsics.
        color_intrinsics: Colour camera intrinsics.
        T_depth_color: Colour → depth camera transform.
        depth_scale: Raw depth units per metre.
        params: Thresholds.
        seed: Seed of the RANSAC sampler (results are reproducible).
    """

    def __init__(self, depth_intrinsics: CameraIntrinsics, color_intrinsics: CameraIntrinsics,
                 T_depth_color: ArrayLike, depth_scale: float = 1000.0,
                 params: CornerParams | None = None, seed: int = 0) -> None:
        self.di = depth_intrinsics
        self.ci = color_intrinsics
        self.T_depth_color = np.asarray(T_depth_color, dtype=float)
        self.T_color_depth = invert_transform(self.T_depth_color)
        self.depth_scale = depth_scale
        self.params = params or CornerParams()
        self.rng = np.random.default_rng(seed)

    def _project_color(self, pts_c: FloatArray) -> FloatArray:
        if self.ci.dist and np.any(np.asarray(self.ci.dist) != 0):
            uv, _ = cv2.projectPoints(pts_c.reshape(-1, 1, 3), np.zeros(3), np.zeros(3),
                                      self.ci.K, self.ci.dist_array)
            return np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        z = pts_c[:, 2]
        return np.stack([self.ci.fx * pts_c[:, 0] / z + self.ci.cx,
                         self.ci.fy * pts_c[:, 1] / z + self.ci.cy], axis=1)

    def _depth_roi(self, quad: FloatArray, shape: tuple[int, int]) -> tuple[slice, slice]:
        """Depth-image window that can hold the marker: the quad's corner rays from 0.2 m to
        20 m projected into the depth camera (a short epipolar segment: the cameras are a
        few centimetres apart)."""
        rays = _undistorted_rays(quad, self.ci)
        pts = np.concatenate([rays * 0.2, rays * 20.0])
        T = self.T_depth_color
        q = pts @ T[:3, :3].T + T[:3, 3]
        q = q[q[:, 2] > 1e-3]
        h, w = shape
        if len(q) == 0:
            return slice(0, 0), slice(0, 0)
        u = self.di.fx * q[:, 0] / q[:, 2] + self.di.cx
        v = self.di.fy * q[:, 1] / q[:, 2] + self.di.cy
        u0, u1 = int(max(np.floor(u.min()) - 2, 0)), int(min(np.ceil(u.max()) + 3, w))
        v0, v1 = int(max(np.floor(v.min()) - 2, 0)), int(min(np.ceil(v.max()) + 3, h))
        return slice(v0, max(v0, v1)), slice(u0, max(u0, u1))

    def frame(
        self, depth: ArrayLike, detections: Sequence[MarkerDetection]
    ) -> dict[int, FrameCorners | str]:
        """Corners (or a rejection reason) per detected marker id in one frame.

        Args:
            depth: ``(H, W)`` depth image of the frame (the estimator's depth camera).
            detections: The markers detected in the frame's colour image.

        Returns:
            Marker id -> its 3D corners in the depth camera frame (m), or why they could not
            be computed.

        Raises:
            InputError: the depth image's size differs from the depth camera's.
        """
        out: dict[int, FrameCorners | str] = {}
        d = np.asarray(depth)
        if d.shape != (self.di.height, self.di.width):
            raise InputError(f"depth image is {d.shape[1]}×{d.shape[0]} but the depth "
                             f"intrinsics are for {self.di.width}×{self.di.height}")
        T = self.T_color_depth
        for det in detections:
            rows, cols = self._depth_roi(det.corners_px, d.shape)
            z = d[rows, cols].astype(np.float64) / self.depth_scale
            vs, us = np.nonzero(np.isfinite(z) & (z > 0.05))
            zz = z[vs, us]
            # a depth camera with a lens model (Azure Kinect: its factory Brown–Conrady
            # coefficients) unprojects along undistorted rays, not the pinhole's
            rays = _undistorted_rays(np.column_stack([us + cols.start, vs + rows.start])
                                     .astype(np.float64), self.di)
            pts_d = rays * zz[:, None]
            pts_c = pts_d @ T[:3, :3].T + T[:3, 3]
            pts_c = pts_c[pts_c[:, 2] > 0.05]
            out[det.id] = self._marker(det, pts_c, self._project_color(pts_c))
        return out

    def _marker(self, det: MarkerDetection, pts_c: FloatArray, uv: FloatArray
                ) -> FrameCorners | str:
        p = self.params
        quad = det.corners_px
        cen = quad.mean(axis=0)
        q = cen + p.shrink * (quad - cen)
        lo, hi = q.min(axis=0), q.max(axis=0)
        box = (uv[:, 0] >= lo[0]) & (uv[:, 0] <= hi[0]) & (uv[:, 1] >= lo[1]) & (uv[:, 1] <= hi[1])
        sel = np.flatnonzero(box)
        sel = sel[_inside_quad(uv[sel], q)]
        if sel.size < p.min_points:
            return (f"only {sel.size} depth points inside the marker (need {p.min_points}): "
                    "it is beyond the depth range, too small or too oblique for this sensor")
        pts = pts_c[sel]
        fit = fit_plane(pts, p, self.rng)
        if fit is None:
            return "no plane fits the depth points inside the marker"
        plane, rms, inl = fit
        frac = float(inl.mean())
        if frac < p.min_inlier_fraction:
            return (f"only {frac:.0%} of the depth points inside the marker lie on one plane: "
                    "the marker is partly occluded or not flat")
        if rms > p.max_plane_rms_m:
            return (f"poor plane fit (RMS {rms * 1000:.1f} mm > {p.max_plane_rms_m * 1000:.0f} mm):"
                    " the marker is not flat or the depth is too noisy there")
        n, d = plane[:3], plane[3]
        rays = _undistorted_rays(quad, self.ci)  # (4, 3), z = 1
        nr = rays @ n
        cosang = np.abs(nr) / np.linalg.norm(rays, axis=1)
        if np.degrees(np.arcsin(np.clip(cosang.min(), 0, 1))) < p.min_ray_angle_deg:
            return "the camera sees the marker almost edge-on (corner rays graze its plane)"
        t = d / nr
        corners_c = rays * t[:, None]
        # pixel noise → plane: Jacobian of the ray/plane intersection by finite differences
        J = np.empty((4, 3, 2))
        for k, dpx in enumerate(([1.0, 0.0], [0.0, 1.0])):
            r2 = _undistorted_rays(quad + np.asarray(dpx), self.ci)
            c2 = r2 * (d / (r2 @ n))[:, None]
            J[:, :, k] = c2 - corners_c
        area = abs(float(cv2.contourArea(quad.astype(np.float32))))
        sig_px = p.corner_sigma_px + p.corner_sigma_k / np.sqrt(max(area, 1.0))
        cov_px = sig_px**2 * np.einsum("kij,klj->kil", J, J)
        # plane-height uncertainty at each corner (linear regression prediction variance)
        inl_pts = pts[inl]
        m = inl_pts.mean(axis=0)
        u_ax = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        u_ax /= np.linalg.norm(u_ax)
        v_ax = np.cross(n, u_ax)
        B = np.stack([u_ax, v_ax], axis=1)  # (3, 2) in-plane basis
        A = (inl_pts - m) @ B
        C = np.cov(A.T) + 1e-9 * np.eye(2)
        dc = (corners_c - m) @ B
        lever = 1.0 + np.einsum("ki,ij,kj->k", dc, np.linalg.inv(C), dc)
        var_h = rms**2 / inl_pts.shape[0] * lever
        dir_h = rays / nr[:, None]  # corner displacement per unit plane offset
        cov_pl = var_h[:, None, None] * np.einsum("ki,kj->kij", dir_h, dir_h)
        R = self.T_depth_color[:3, :3]
        corners_d = transform_points(self.T_depth_color, corners_c)
        rot = lambda S: np.einsum("ij,kjl,ml->kim", R, S, R)  # noqa: E731
        return FrameCorners(corners_d, rot(cov_px), rot(cov_pl), int(inl.sum()), rms)


def average_observation(
    sensor_id: str,
    marker_id: int,
    per_frame: Sequence[FrameCorners | str],
    n_seen: int,
    n_total: int,
    params: CornerParams | None = None,
    corners_px: FloatArray | None = None,
) -> Observation:
    """Average one marker's per-frame corners into an :class:`Observation`.

    Frames whose corners stray from the median by more than 4 σ (someone walked over the
    marker, a depth glitch) are dropped before averaging.

    Args:
        sensor_id: The sensor.
        marker_id: The marker.
        per_frame: Per frame the 3D corners, or the reason they could not be computed.
        n_seen: Frames in which the marker was detected.
        n_total: Frames captured.
        params: Thresholds (defaults when None).
        corners_px: The marker's image corners (kept for display).

    Returns:
        The observation, accepted or rejected with its reason.
    """
    p = params or CornerParams()
    min_frames = p.min_frames if p.min_frames is not None else max(2, int(np.ceil(0.3 * n_total)))
    min_frames = min(min_frames, max(n_total, 1)) if n_total > 1 else 2
    good = [f for f in per_frame if isinstance(f, FrameCorners)]
    reasons = [f for f in per_frame if isinstance(f, str)]
    px = np.full((4, 2), np.nan) if corners_px is None else corners_px
    obs = Observation(sensor_id, marker_id, False, n_frames=len(good), n_frames_seen=n_seen,
                      corners_px=px)
    if n_seen <= 1:
        obs.reason = (f"marker {marker_id} seen in {n_seen} frame only (need {min_frames} of "
                      f"{n_total}): keep the sensor still and the marker in view while capturing")
        if good:
            obs.corners = good[0].corners
        return obs
    if len(good) < min_frames:
        common = max(set(reasons), key=reasons.count) if reasons else "marker not detected"
        obs.reason = (f"usable in {len(good)} of {n_total} frames (need {min_frames}): {common}")
        return obs
    C = np.stack([f.corners for f in good])  # (F, 4, 3)
    med = np.median(C, axis=0)
    sd = np.sqrt(np.stack([np.trace(f.cov[k] + f.cov_plane[k]) for f in good
                           for k in range(4)]).reshape(len(good), 4).mean(axis=0) / 3)
    dev = np.linalg.norm(C - med, axis=2)  # (F, 4)
    keep = np.all(dev <= 4 * np.maximum(sd, 0.002), axis=1)
    if keep.sum() < min_frames:
        keep = np.ones(len(good), bool)
    kept = [f for f, k in zip(good, keep, strict=True) if k]
    nf = len(kept)
    obs.corners = np.mean([f.corners for f in kept], axis=0)
    # pixel noise is the same image feature every frame (not averaged away); plane noise is
    obs.cov = (np.mean([f.cov for f in kept], axis=0)
               + np.mean([f.cov_plane for f in kept], axis=0) / nf
               + (0.0003**2) * np.eye(3)[None])
    obs.n_frames = nf
    obs.n_points = float(np.mean([f.n_points for f in kept]))
    obs.plane_rms_m = float(np.mean([f.plane_rms_m for f in kept]))
    obs.distance_m = float(np.linalg.norm(obs.corners.mean(axis=0)))
    obs.accepted = True
    return obs


def robust_mean_image(images: Sequence[NDArray[np.uint8]], max_frames: int = 9
                      ) -> NDArray[np.uint8]:
    """Per-pixel temporal median of up to ``max_frames`` evenly spaced images.

    The sensor and markers are still during capture, so the median keeps the markers and
    removes image noise and transients (a person walking past, a flicker).

    Args:
        images: The frames (same shape, uint8).
        max_frames: Most frames used.

    Returns:
        The median image, uint8.
    """
    if len(images) == 1:
        return np.asarray(images[0])
    idx = np.unique(np.linspace(0, len(images) - 1, min(max_frames, len(images))).round()
                    .astype(int))
    stack = np.stack([np.asarray(images[i]) for i in idx])
    return np.median(stack, axis=0).round().astype(np.uint8)


def observe_sensor(
    frames: SensorFrames,
    marker_ids: Mapping[int, float] | None = None,
    dictionary: str = DEFAULT_DICTIONARY,
    params: CornerParams | None = None,
) -> list[Observation]:
    """Detect markers in every frame of one sensor and average their 3D corners.

    Every colour frame is searched (to count in how many frames each marker is seen and
    to catch duplicated ids); the sub-pixel corners come from the temporal median image
    refined by the pattern fit (:func:`engine.calibration.detect.refine_corners_template`);
    the plane is fitted per depth frame and the corners averaged.

    Args:
        frames: The sensor's frames and camera model.
        marker_ids: Marker id → edge length (m) of the markers in the room; other ids
            found in the images are ignored (stray prints). ``None`` keeps every id.
        dictionary: Marker dictionary.
        params: Thresholds.

    Returns:
        One :class:`Observation` per marker id seen in any frame (accepted or not).

    Raises:
        InputError: no depth frames (a colour-only sensor cannot be calibrated), or
            colour and depth frame counts differ.
    """
    sid = frames.sensor_id
    if frames.depths is None or len(frames.depths) == 0:
        raise InputError(f"sensor {sid} sent no depth frames: calibration needs depth "
                         "(check that the depth stream of this sensor is enabled)")
    if len(frames.colors) != len(frames.depths):
        raise InputError(f"sensor {sid}: {len(frames.colors)} colour but "
                         f"{len(frames.depths)} depth frames")
    params = params or CornerParams()
    d0 = np.asarray(frames.depths[0])
    c0 = np.asarray(frames.colors[0])
    di = _intr(frames.depth_intrinsics, d0.shape)
    ci = _intr(frames.color_intrinsics, c0.shape)
    est = FrameCornerEstimator(di, ci, frames.T_depth_color, frames.depth_scale, params)
    detector = make_detector(dictionary)
    n_total = len(frames.depths)
    per_frame_ids: list[set[int]] = []
    seen: dict[int, int] = {}
    first: dict[int, MarkerDetection] = {}
    dup_ids: set[int] = set()
    for img in frames.colors:
        # per frame only which ids are seen, so without the lens (undistorting every frame
        # would double the detection time): the corners come from the median image,
        # detected through the lens; a marker the median lost falls back to its first
        # frame's corners, in the image's own pixels, which the estimator undistorts
        ds = detect_markers(img, dictionary, detector=detector, refine=False)
        dup_ids.update(ds.duplicates)
        ids = {m.id for m in ds.markers if marker_ids is None or m.id in marker_ids}
        per_frame_ids.append(ids)
        for m in ds.markers:
            if m.id in ids:
                seen[m.id] = seen.get(m.id, 0) + 1
                first.setdefault(m.id, m)
    median = detect_with_lens(robust_mean_image(frames.colors), ci, dictionary, detector)
    best = {m.id: m for m in median.markers}
    dets = {mid: best.get(mid, first[mid]) for mid in seen}
    per: dict[int, list[FrameCorners | str]] = {mid: [] for mid in seen}
    for depth, ids in zip(frames.depths, per_frame_ids, strict=True):
        use = [dets[i] for i in sorted(ids) if i not in dup_ids]
        for mid, fc in est.frame(depth, use).items():
            per[mid].append(fc)
    out: list[Observation] = []
    for mid in sorted(set(seen) | dup_ids):
        if marker_ids is not None and mid not in marker_ids:
            continue
        if mid in dup_ids:
            out.append(Observation(sid, mid, False, reason=(
                f"marker id {mid} appears more than once in {sid}'s image: two printed copies "
                "of one id make its pose ambiguous; remove or replace one of them")))
            continue
        out.append(average_observation(sid, mid, per[mid], seen.get(mid, 0), n_total, params,
                                       dets[mid].corners_px))
    return out
