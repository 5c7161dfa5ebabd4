"""Marker detection in colour images with sub-pixel corners, and single-marker pose.

Detection uses OpenCV's ``ArucoDetector`` with sub-pixel corner refinement, then (by
default) aligns the marker's known pattern to the image: an ECC homography fit
(``cv2.findTransformECC``) of the ideal marker image, started from the detected corners.
Corner refinement alone looks at a few pixels around each corner and is biased on small,
foreshortened markers (a floor marker 4 m away is a thin diamond with acute corners: errors
of 0.5–2.5 px in our simulation); the template fit uses every edge of the code and brings
that to ≈ 0.1 px, and on real photos of a ChArUco board it lowers the per-marker
reprojection RMS from ≤ 0.8 px to ≤ 0.2 px. The fit is kept only when it correlates well
and moves the corners little, so it can only refine, never relocate, a detection.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.calibration.markers import (
    DEFAULT_DICTIONARY,
    dictionary_name,
    get_dictionary,
    marker_model_corners,
)
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
        """Ids of the detected markers, in detection order."""
        return [m.id for m in self.markers]

    def get(self, marker_id: int) -> MarkerDetection | None:
        """Detection of ``marker_id``, or None.

        Args:
            marker_id: The marker's dictionary id.

        Returns:
            The detection, or None when the marker was not found.
        """
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
    """An ``ArucoDetector`` for ``dictionary`` with sub-pixel corner refinement.

    Args:
        dictionary: Marker dictionary name.
        subpix: Refine corners to sub-pixel precision.

    Returns:
        The OpenCV detector.

    Raises:
        InputError: unknown dictionary.
    """
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
        elif img.dtype == np.uint16:  # a 16-bit PNG/TIFF photo: full range, not clipped
            img = img / 257.0
        img = np.clip(np.round(img), 0, 255).astype(np.uint8)
    return img


#: photo file types read by :func:`load_image`
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp")


def load_image(path: str | Path) -> NDArray[np.uint8]:
    """Read a photo for marker detection: ``(H, W, 3)`` RGB or ``(H, W)`` grey, uint8,
    upright.

    JPEG EXIF orientation is applied (a phone's portrait photo is stored landscape with a
    tag), 16-bit PNG/TIFF photos are scaled to 8 bits, an alpha channel is dropped and a
    grey photo stays grey (detection uses intensity only).

    Args:
        path: A JPEG, PNG, TIFF, BMP or WebP photo.

    Returns:
        The image as uint8 array, RGB or grey.

    Raises:
        InputError: missing file, unsupported type or an undecodable image.
    """
    p = Path(path)
    if p.suffix.lower() not in IMAGE_SUFFIXES:
        raise InputError(f"{p.name}: unsupported photo type {p.suffix or '(none)'!r}; use "
                         + ", ".join(IMAGE_SUFFIXES))
    if not p.is_file():
        raise InputError(f"cannot read {p}: no such file")
    # IMREAD_ANYDEPTH | IMREAD_ANYCOLOR keeps 16 bits and grey; without IMREAD_UNCHANGED
    # OpenCV applies the EXIF orientation
    img = cv2.imread(str(p), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
    if img is None or img.size == 0:
        raise InputError(f"{p.name}: not a readable image (damaged, truncated or another "
                         "format); export it again as JPEG or PNG")
    if img.ndim == 3:
        img = cv2.cvtColor(img[..., :3], cv2.COLOR_BGR2RGB)
    if img.dtype != np.uint8:
        img = _to_gray(img) if img.ndim == 2 else np.clip(
            np.round(img / 257.0), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(img)


def camera_for_image(
    K: ArrayLike, dist: ArrayLike | None, calib_size: tuple[int, int],
    image_size: tuple[int, int],
) -> tuple[FloatArray, FloatArray | None]:
    """The camera matrix for a photo taken at another resolution than the calibration.

    The same sensor at another resolution (same aspect ratio, e.g. a 4K photo with a
    640×480 calibration, or 320×240 previews) scales the focal lengths and the principal
    point (pixel centres: ``c' = (c + 0.5)·s - 0.5``); distortion coefficients act on
    normalised coordinates and stay. A photo rotated by 90° (portrait) or of another aspect
    ratio cannot be matched to the calibration: that is refused.

    Args:
        K: 3×3 calibrated camera matrix.
        dist: its distortion coefficients (or None).
        calib_size: ``(width, height)`` the calibration was made at.
        image_size: ``(width, height)`` of the photo.

    Returns:
        ``(K, dist)`` for the photo's size (the inputs when the sizes are equal).

    Raises:
        InputError: a portrait photo with a landscape calibration (or the reverse), or
            another aspect ratio.
    """
    Km = np.asarray(K, dtype=float)
    d = None if dist is None else np.asarray(dist, dtype=float)
    (cw, ch), (w, h) = calib_size, image_size
    if (w, h) == (cw, ch):
        return Km, d
    sx, sy = w / cw, h / ch
    if abs(sx - sy) > 0.01 * max(sx, sy):
        if abs(w / ch - h / cw) <= 0.01 * max(w / ch, h / cw):
            raise InputError(
                f"the photo is {w}×{h} but the camera was calibrated at {cw}×{ch}: it is "
                "rotated by 90° (portrait); rotate it back to the calibration's orientation "
                "or calibrate the camera in portrait")
        raise InputError(f"the photo is {w}×{h} but the camera was calibrated at {cw}×{ch} "
                         "(another aspect ratio: cropped?); use the calibration's "
                         "resolution or calibrate at this one")
    S = np.array([[sx, 0.0, 0.5 * (sx - 1.0)], [0.0, sy, 0.5 * (sy - 1.0)], [0.0, 0.0, 1.0]])
    return S @ Km, d


#: images smaller than this (longer side, px) are detected at an integer multiple of
#: their size: a 320×240 photo of a ChArUco board has 2-px code cells, where OpenCV finds
#: 5 of 17 markers; cubic 2× upsampling finds 16, board pose within 0.11 mm / 0.06°
_MIN_DETECT_SIDE_PX = 640


def _upsampling(shape: tuple[int, ...]) -> int:
    """Integer factor that brings an image's longer side to 640 px (at most 4)."""
    side = max(shape[:2])
    return int(min(4, -(-_MIN_DETECT_SIDE_PX // max(side, 1)))) if side < _MIN_DETECT_SIDE_PX \
        else 1


#: dictionaries tried by :func:`find_dictionary`, the common ones first (AprilTag 16h5,
#: with few bits, last: it finds the odd false marker in any textured image)
COMMON_DICTIONARIES = ("DICT_4X4_50", "DICT_5X5_100", "DICT_6X6_250", "DICT_7X7_250",
                       "DICT_ARUCO_ORIGINAL", "DICT_APRILTAG_36h11", "DICT_APRILTAG_25h9",
                       "DICT_APRILTAG_16h5", "DICT_ARUCO_MIP_36h12")


def find_dictionary(image: ArrayLike, exclude: str | None = None) -> tuple[str, int] | None:
    """The marker dictionary that finds the most markers in ``image`` (and how many),
    or ``None`` when none of :data:`COMMON_DICTIONARIES` finds any.

    A marker of one family is read as an id of another only rarely (each dictionary
    keeps its codes far apart), so the family finding the most markers is the one
    printed; a single marker is not enough (a false one turns up in textured images).
    One size per family is tried (``DICT_6X6_250``): the ``_50/100/250/1000`` sizes share
    their first codes.

    Args:
        image: The photo or frame, uint8.
        exclude: A dictionary not to try (the one that already failed).

    Returns:
        ``(dictionary name, markers found)`` or None.
    """
    gray = _to_gray(image)
    up = _upsampling(gray.shape)
    if up > 1:
        gray = np.asarray(cv2.resize(gray, None, fx=up, fy=up, interpolation=cv2.INTER_CUBIC),
                          dtype=np.uint8)
    best: tuple[str, int] | None = None
    for name in COMMON_DICTIONARIES:
        if exclude is not None and name.upper() == dictionary_name(exclude).upper():
            continue
        _, ids, _ = make_detector(name, subpix=False).detectMarkers(gray)
        n = 0 if ids is None else len(ids)
        if n >= 2 and (best is None or n > best[1]):
            best = (name, n)
    return best


def no_markers_error(image: ArrayLike, dictionary: str) -> InputError:
    """The error for an image where ``dictionary`` finds no marker.

    It names the dictionary that does find markers in the image when there is one.

    Args:
        image: The image.
        dictionary: The dictionary that found nothing.

    Returns:
        The :class:`InputError` to raise.
    """
    found = find_dictionary(image, exclude=dictionary)
    if found is not None:
        return InputError(f"no {dictionary} marker in the image, but {found[1]} "
                          f"{found[0]} marker(s): the markers were printed from another "
                          f"dictionary; set the dictionary to {found[0]}")
    return InputError(f"no {dictionary} marker in the image: check that the markers are in "
                      "view, lit, sharp and at least ~20 pixels wide")


def _lens(K: ArrayLike | None, dist: ArrayLike | None, shape: tuple[int, ...]
          ) -> tuple[FloatArray, FloatArray, NDArray[np.float32], NDArray[np.float32]] | None:
    """``(K, dist, map_x, map_y)`` undistorting an image of ``shape`` (same K), or None
    without distortion."""
    if K is None or dist is None:
        return None
    Km = np.asarray(K, dtype=float)
    d = np.asarray(dist, dtype=float).ravel()
    if Km.shape != (3, 3):
        raise InputError("K must be a 3×3 camera matrix")
    if not np.any(d):
        return None
    h, w = shape[:2]
    mx, my = cv2.initUndistortRectifyMap(Km, d, None, Km, (w, h), cv2.CV_32FC1)
    return Km, d, np.asarray(mx, np.float32), np.asarray(my, np.float32)


def _distort_px(px: FloatArray, K: FloatArray, dist: FloatArray) -> FloatArray:
    """Undistorted pixels (camera ``K``) → the distorted image's pixels."""
    xn = (px - K[:2, 2]) / np.diag(K)[:2]
    obj = np.column_stack([xn, np.ones(len(xn))])
    out, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), K, dist)
    return np.asarray(out, dtype=float).reshape(-1, 2)


_ECC_CELL_PX = 8  # template pixels per code cell
_ECC_MIN_CORR = 0.7


def refine_corners_template(
    gray: NDArray[np.uint8],
    det: MarkerDetection,
    dictionary: str = DEFAULT_DICTIONARY,
    max_shift_px: float | None = None,
) -> MarkerDetection:
    """Refine a detection by fitting the ideal marker image to ``gray`` (ECC homography).

    The template is the marker with one cell of white quiet zone (printed sheets and
    ChArUco boards have at least that). The refined corners are returned only when the
    correlation is ≥ 0.7 and no corner moved more than ``max_shift_px`` (default: the
    larger of 2 px and 10 % of the marker's mean edge); otherwise ``det`` unchanged.

    Args:
        gray: The grey image.
        det: The detection to refine.
        dictionary: Marker dictionary name.
        max_shift_px: Largest corner move accepted, px (None: see above).

    Returns:
        The refined detection, or ``det``.
    """
    from engine.calibration.markers import marker_image

    d = get_dictionary(dictionary)
    cells = int(d.markerSize) + 2
    side = cells * _ECC_CELL_PX
    pad = _ECC_CELL_PX
    tpl = np.pad(marker_image(det.id, side, dictionary), pad, constant_values=255)
    src = np.array([[pad, pad], [pad + side, pad], [pad + side, pad + side],
                    [pad, pad + side]], np.float32) - 0.5  # outer edges, pixel-centre coords
    H0 = cv2.getPerspectiveTransform(src, det.corners_px.astype(np.float32))
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-6)
    try:
        # no mask (None; the stubs do not allow it); gaussFiltSize 1 = no blur, which keeps
        # the template sharp: the image is already band-limited by the camera
        corr, H = cv2.findTransformECC(  # type: ignore[call-overload]
            tpl.astype(np.float32), gray.astype(np.float32), H0.astype(np.float32),
            cv2.MOTION_HOMOGRAPHY, crit, None, 1)
    except cv2.error:  # did not converge (e.g. marker at the image border)
        return det
    c = cv2.perspectiveTransform(src.reshape(-1, 1, 2), H).reshape(4, 2).astype(float)
    edge = det.perimeter_px / 4.0
    limit = max_shift_px if max_shift_px is not None else max(2.0, 0.1 * edge)
    if (not np.isfinite(c).all() or corr < _ECC_MIN_CORR
            or np.linalg.norm(c - det.corners_px, axis=1).max() > limit):
        return det
    return MarkerDetection(det.id, c)


def detect_markers(
    image: ArrayLike,
    dictionary: str = DEFAULT_DICTIONARY,
    detector: cv2.aruco.ArucoDetector | None = None,
    refine: bool = True,
    require: bool = False,
    K: ArrayLike | None = None,
    dist: ArrayLike | None = None,
) -> DetectionSet:
    """Detect markers with sub-pixel corners.

    Args:
        image: (H, W, 3) colour (RGB or BGR: detection uses intensity only) or (H, W) grey.
        dictionary: Dictionary name (also used for the template refinement).
        detector: A reusable detector from :func:`make_detector` (saves setup per frame).
        refine: Refine the corners by fitting the marker's pattern
            (:func:`refine_corners_template`).
        require: Raise when no marker is found (naming the dictionary the markers are
            from, when another one finds them: :func:`no_markers_error`) instead of
            returning an empty set.
        K: The camera matrix, with ``dist``: a lens with distortion bends the markers'
            edges, which the detector's quads and the pattern fit (a homography) take
            straight. With both given, markers are found in the undistorted image and
            their corners distorted back, so the result is in the image's own pixels as
            without them (a marker only found in the photo as it is is kept as found
            there) (on the real ChArUco photo through a strong barrel lens, board
            pose 0.11 mm / 0.16° off without, 0.03 mm / 0.01° with).
        dist: OpenCV distortion coefficients of ``K``'s camera.

    Returns:
        The unique-id detections and the list of duplicated ids.

    Raises:
        InputError: image of the wrong shape; no marker with ``require``.
    """
    gray = _to_gray(image)
    lens = _lens(K, dist, gray.shape)
    if lens is not None:
        Km, d, mx, my = lens
        und = np.asarray(cv2.remap(gray, mx, my, cv2.INTER_CUBIC, borderValue=255),
                         dtype=np.uint8)
        inner = detect_markers(und, dictionary, detector, refine)
        # markers the undistortion lost (it resamples; it pushes the corners' content
        # out of the frame) are taken from the photo as it is: never fewer than without
        plain = detect_markers(gray, dictionary, detector, refine)
        dups = sorted(set(inner.duplicates) | set(plain.duplicates))
        best = {m.id: MarkerDetection(m.id, _distort_px(m.corners_px, Km, d))
                for m in inner.markers}
        for m in plain.markers:
            best.setdefault(m.id, m)
        if not best and not dups and require:
            raise no_markers_error(gray, dictionary)
        return DetectionSet([best[i] for i in sorted(best) if i not in dups], dups)
    up = _upsampling(gray.shape)
    if up > 1:  # small images: see _upsampling; corners are mapped back below
        gray = np.asarray(cv2.resize(gray, None, fx=up, fy=up, interpolation=cv2.INTER_CUBIC),
                          dtype=np.uint8)
    det = detector or make_detector(dictionary)
    corners, ids, _ = det.detectMarkers(gray)
    if ids is None or len(ids) == 0:
        if require:
            raise no_markers_error(gray, dictionary)
        return DetectionSet()
    id_list = [int(i) for i in np.asarray(ids).ravel()]
    counts = Counter(id_list)
    dups = sorted(i for i, n in counts.items() if n > 1)
    found = [
        MarkerDetection(i, np.asarray(c, dtype=float).reshape(4, 2))
        for i, c in zip(id_list, corners, strict=True)
        if counts[i] == 1
    ]
    if refine:
        found = [refine_corners_template(gray, m, dictionary) for m in found]
    if up > 1:  # pixel centres: x = (x_up + 0.5) / up - 0.5
        found = [MarkerDetection(m.id, (m.corners_px + 0.5) / up - 0.5) for m in found]
    found.sort(key=lambda m: m.id)
    return DetectionSet(found, dups)


def reprojection_rms(
    T_camera_marker: ArrayLike,
    corners_px: ArrayLike,
    size_m: float,
    K: ArrayLike,
    dist: ArrayLike | None = None,
) -> float:
    """RMS distance (pixels) between observed corners and the projected model corners.

    Args:
        T_camera_marker: 4×4 marker pose in the camera frame (m).
        corners_px: ``(4, 2)`` observed corners, OpenCV order.
        size_m: Marker edge length, m.
        K: 3×3 camera matrix.
        dist: Distortion coefficients, or None.

    Returns:
        The RMS, pixels.
    """
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

    Returns:
        ``T_camera_marker`` (4×4, marker → camera, metres) and the reprojection RMS
        (pixels).

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
    # IPPE gives the closed-form planar solution; LM then minimises the reprojection error
    rvec, tvec = cv2.solvePnPRefineLM(marker_model_corners(size_m), c, Km, d, rvec, tvec)
    R, _ = cv2.Rodrigues(rvec)
    T = make_transform(R, np.asarray(tvec, dtype=float).ravel())
    return MarkerPose(T, reprojection_rms(T, c, size_m, Km, d))
