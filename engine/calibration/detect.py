"""Marker detection in colour images with sub-pixel corners, and single-marker pose.

Detection uses OpenCV's ``ArucoDetector`` with sub-pixel corner refinement, which is what
makes 3D corners from depth and the per-marker pose accurate to a fraction of a pixel.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.calibration.markers import DEFAULT_DICTIONARY, get_dictionary, marker_model_corners
from engine.errors import InputError
from engine.geometry import make_transform

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class MarkerDetection:
    """One detected marker.

    Attributes:
        id: Marker id in the dictionary.
        corners_px: (4, 2) pixel corners, OpenCV order TL, TR, BR, BL of the printed marker.
    """

    id: int
    corners_px: FloatArray

    @property
    def perimeter_px(self) -> float:
        """Perimeter of the quad in pixels (a proxy for how well it is resolved)."""
        c = self.corners_px
        return float(np.linalg.norm(c - np.roll(c, -1, axis=0), axis=1).sum())


@dataclass
class DetectionSet:
    """Markers found in one image.

    Attributes:
        markers: Detections with a unique id in this image, sorted by id.
        duplicates: Ids seen more than once in the image (excluded from ``markers``
            because their pose is ambiguous: two printed copies of one id).
    """

    markers: list[MarkerDetection] = field(default_factory=list)
    duplicates: list[int] = field(default_factory=list)

    @property
    def ids(self) -> list[int]:
        return [m.id for m in self.markers]

    def get(self, marker_id: int) -> MarkerDetection | None:
        """Detection of ``marker_id`` or None."""
        for m in self.markers:
            if m.id == marker_id:
                return m
        return None


@dataclass(frozen=True)
class MarkerPose:
    """Pose of one marker from its image corners (PnP).

    Attributes:
        T_camera_marker: 4×4 marker → camera transform.
        rms_px: Reprojection RMS of the four corners (pixels).
    """

    T_camera_marker: FloatArray
    rms_px: float


def make_detector(
    dictionary: str = DEFAULT_DICTIONARY, subpix: bool = True
) -> cv2.aruco.ArucoDetector:
    """An ``ArucoDetector`` for ``dictionary`` with sub-pixel corner refinement."""
    params = cv2.aruco.DetectorParameters()
    if subpix:
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        params.cornerRefinementWinSize = 5
        params.cornerRefinementMaxIterations = 50
        params.cornerRefinementMinAccuracy = 0.01
    return cv2.aruco.ArucoDetector(get_dictionary(dictionary), params)


def _to_gray(image: ArrayLike) -> NDArray[np.uint8]:
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        img = cv2.cvtColor(img[..., :3].astype(np.uint8), cv2.COLOR_RGB2GRAY)
    elif img.ndim != 2:
        raise InputError(f"image must be (H, W) grey or (H, W, 3) colour, got shape {img.shape}")
    if img.dtype != np.uint8:
        if np.issubdtype(img.dtype, np.floating) and img.max(initial=0) <= 1.0:
            img = img * 255.0
        img = np.clip(img, 0, 255).astype(np.uint8)
    return img


def detect_markers(
    image: ArrayLike,
    dictionary: str = DEFAULT_DICTIONARY,
    detector: cv2.aruco.ArucoDetector | None = None,
) -> DetectionSet:
    """Detect markers with sub-pixel corners.

    Args:
        image: (H, W, 3) colour (RGB or BGR: detection uses intensity only) or (H, W) grey.
        dictionary: Dictionary name (ignored when ``detector`` is given).
        detector: A reusable detector from :func:`make_detector` (saves setup per frame).

    Returns:
        The unique-id detections and the list of duplicated ids.

    Raises:
        InputError: image of the wrong shape.
    """
    gray = _to_gray(image)
    det = detector or make_detector(dictionary)
    corners, ids, _ = det.detectMarkers(gray)
    if ids is None or len(ids) == 0:
        return DetectionSet()
    id_list = [int(i) for i in np.asarray(ids).ravel()]
    counts = Counter(id_list)
    dups = sorted(i for i, n in counts.items() if n > 1)
    found = [
        MarkerDetection(i, np.asarray(c, dtype=float).reshape(4, 2))
        for i, c in zip(id_list, corners, strict=True)
        if counts[i] == 1
    ]
    found.sort(key=lambda m: m.id)
    return DetectionSet(found, dups)


def reprojection_rms(
    T_camera_marker: ArrayLike,
    corners_px: ArrayLike,
    size_m: float,
    K: ArrayLike,
    dist: ArrayLike | None = None,
) -> float:
    """RMS distance (pixels) between observed corners and the projected model corners."""
    T = np.asarray(T_camera_marker, dtype=float)
    rvec, _ = cv2.Rodrigues(T[:3, :3])
    proj, _ = cv2.projectPoints(
        marker_model_corners(size_m), rvec, T[:3, 3], np.asarray(K, dtype=float),
        None if dist is None else np.asarray(dist, dtype=float),
    )
    d = proj.reshape(4, 2) - np.asarray(corners_px, dtype=float).reshape(4, 2)
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


def estimate_marker_pose(
    corners_px: ArrayLike, size_m: float, K: ArrayLike, dist: ArrayLike | None = None
) -> MarkerPose:
    """Marker pose in the camera frame from its four corners (``SOLVEPNP_IPPE_SQUARE``).

    Args:
        corners_px: (4, 2) corners in OpenCV order.
        size_m: Printed edge length (m).
        K: 3×3 camera matrix.
        dist: Distortion coefficients or None.

    Raises:
        InputError: wrong shapes or PnP failure.
    """
    c = np.asarray(corners_px, dtype=float).reshape(-1, 2)
    if c.shape != (4, 2):
        raise InputError(f"a marker has 4 corners, got {c.shape[0]}")
    Km = np.asarray(K, dtype=float)
    if Km.shape != (3, 3):
        raise InputError("K must be a 3×3 camera matrix")
    d = None if dist is None else np.asarray(dist, dtype=float)
    ok, rvec, tvec = cv2.solvePnP(
        marker_model_corners(size_m), c, Km, d, flags=cv2.SOLVEPNP_IPPE_SQUARE
    )
    if not ok:
        raise InputError("solvePnP failed for this marker (degenerate corners)")
    R, _ = cv2.Rodrigues(rvec)
    T = make_transform(R, np.asarray(tvec, dtype=float).ravel())
    return MarkerPose(T, reprojection_rms(T, c, size_m, Km, d))
