"""Calibration photos as other cameras, phones and labs take them.

The real ChArUco photos (``markers/charuco/choriginal.jpg``, ``chocclusion_original.jpg``,
640×480, OpenCV's tutorial board: 6×6 markers of 2 cm) and their calibration
(``tutorial_camera_charuco.yml``) are rewritten at other resolutions (320×240 to 3840×2880),
rotated to portrait, stored with an EXIF orientation tag, in grey, as PNG (8/16 bit,
alpha), through a strongly distorting lens, and detected with the wrong dictionary.

Measure: the board pose fitted to every detected marker's corners (``solvePnP`` on the
board's layout) against the one from the original photo. Single 2 cm markers seen nearly
face-on are not used for this: their pose has two near-equal solutions (IPPE), and which
one wins flips on noise of a hundredth of a pixel (83° apart on the 2× image). Tolerances:
bit-exact rewrites (rotation by 90°, PNG, grey, 16 bit) must give the same pose to 1 µm;
resampled ones (resizing, lens remapping, JPEG recompression) add their interpolation
error, and must stay within 0.5 mm / 0.1° (measured: 0.02-0.11 mm, 0.002-0.06°).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from engine.calibration.detect import (
    DetectionSet,
    camera_for_image,
    detect_markers,
    find_dictionary,
    load_image,
)
from engine.errors import InputError

CHARUCO = "markers/charuco"
DICT = "DICT_6X6_250"
ALL_IDS = list(range(17))
OCCLUDED_IDS = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 12, 15]  # a mouse hides 11, 13, 14, 16


def _board() -> cv2.aruco.CharucoBoard:
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)
    return cv2.aruco.CharucoBoard((5, 7), 0.04, 0.02, d)


BOARD = _board()
BOARD_IDS = BOARD.getIds().ravel().tolist()


def board_pose(ds: DetectionSet, K: np.ndarray, dist: np.ndarray | None) -> np.ndarray:
    """T_camera_board from every detected marker's corners."""
    obj = np.concatenate([BOARD.getObjPoints()[BOARD_IDS.index(m.id)] for m in ds.markers])
    img = np.concatenate([m.corners_px for m in ds.markers])
    ok, r, t = cv2.solvePnP(obj, img, K, dist)
    assert ok
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(r)[0]
    T[:3, 3] = t.ravel()
    return T


def pose_diff(T: np.ndarray, T0: np.ndarray) -> tuple[float, float]:
    """(mm, degrees) between two poses."""
    c = (np.trace(T[:3, :3].T @ T0[:3, :3]) - 1) / 2
    return (float(np.linalg.norm(T[:3, 3] - T0[:3, 3]) * 1000),
            float(np.degrees(np.arccos(np.clip(c, -1, 1)))))


class Ref:
    """The original photos, their calibration and reference board poses."""

    def __init__(self, d: Path) -> None:
        fs = cv2.FileStorage(str(d / "tutorial_camera_charuco.yml"), cv2.FILE_STORAGE_READ)
        self.K = fs.getNode("camera_matrix").mat()
        self.dist = fs.getNode("distortion_coefficients").mat().ravel()
        self.size = (int(fs.getNode("image_width").real()),
                     int(fs.getNode("image_height").real()))
        self.photos = {k: load_image(d / f"{k}.jpg") for k in ("choriginal",
                                                                "chocclusion_original")}
        self.poses = {}
        for k, img in self.photos.items():
            ds = detect_markers(img, DICT)
            assert ds.ids == (ALL_IDS if k == "choriginal" else OCCLUDED_IDS)
            self.poses[k] = board_pose(ds, self.K, self.dist)


@pytest.fixture(scope="module")
def ref(shared_data: Path) -> Ref:
    return Ref(shared_data / CHARUCO)


def _check(ref: Ref, photo: str, img: np.ndarray, K: np.ndarray, dist: np.ndarray | None,
           mm: float, deg: float, lost: int = 0,
           R: np.ndarray | None = None) -> tuple[float, float]:
    """Detect, fit the board, compare; ``lost``: how many markers may be missed (never a
    false or extra id)."""
    ds = detect_markers(img, DICT)
    want = ALL_IDS if photo == "choriginal" else OCCLUDED_IDS
    assert set(ds.ids) <= set(want) and len(ds.ids) >= len(want) - lost, ds.ids
    assert ds.duplicates == []
    T = board_pose(ds, K, dist)
    if R is not None:
        T = R @ T
    dt, dr = pose_diff(T, ref.poses[photo])
    assert dt < mm and dr < deg, (dt, dr)
    return dt, dr


# --------------------------------------------------------------------- resolutions


@pytest.mark.parametrize(("photo", "size"), [
    ("choriginal", (320, 240)), ("chocclusion_original", (320, 240)),
    ("choriginal", (960, 720)), ("chocclusion_original", (1280, 960)),
    ("choriginal", (3840, 2880))])
def test_other_resolutions(ref: Ref, photo: str, size: tuple[int, int]) -> None:
    """The same camera at another resolution: intrinsics scaled by camera_for_image.

    At 320×240 the code cells are 2 px wide: detection runs on a 2× upsampled copy
    (OpenCV alone finds 5 of 17 markers there, upsampled 15-16); the board pose from
    those is still within 0.5 mm / 0.1°.
    """
    img = ref.photos[photo]
    small = size[0] < ref.size[0]
    im = cv2.resize(img, size, interpolation=cv2.INTER_AREA if small else cv2.INTER_CUBIC)
    K, dist = camera_for_image(ref.K, ref.dist, ref.size, size)
    _check(ref, photo, im, K, dist, 0.5, 0.1, lost=2 if small else 0)


def test_camera_for_image_refuses_what_it_cannot_match(ref: Ref) -> None:
    K, d = camera_for_image(ref.K, ref.dist, (640, 480), (1280, 960))
    assert K[0, 0] == pytest.approx(2 * ref.K[0, 0]) and K[0, 2] == pytest.approx(
        2 * ref.K[0, 2] + 0.5)
    assert d is not None and np.array_equal(d, ref.dist)
    with pytest.raises(InputError, match="rotated by 90°"):
        camera_for_image(ref.K, ref.dist, (640, 480), (480, 640))
    with pytest.raises(InputError, match="another aspect ratio"):
        camera_for_image(ref.K, ref.dist, (640, 480), (640, 360))


# --------------------------------------------------------------------- orientation


def _rotated_camera(K: np.ndarray, dist: np.ndarray, h: int, w: int, clockwise: bool
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Intrinsics of the image rotated by 90° and T_camera_rotatedcamera.

    Clockwise: u' = h-1-v, v' = u, so x' = -y, y' = x; tangential terms (p1, p2) become
    (p2, -p1). Counter-clockwise: u' = v, v' = w-1-u; (p1, p2) -> (-p2, p1).
    """
    k1, k2, p1, p2, k3 = dist
    R = np.eye(4)
    if clockwise:
        K2 = np.array([[K[1, 1], 0, h - 1 - K[1, 2]], [0, K[0, 0], K[0, 2]], [0, 0, 1]])
        d2 = np.array([k1, k2, p2, -p1, k3])
        R[:3, :3] = [[0, 1, 0], [-1, 0, 0], [0, 0, 1]]
    else:
        K2 = np.array([[K[1, 1], 0, K[1, 2]], [0, K[0, 0], w - 1 - K[0, 2]], [0, 0, 1]])
        d2 = np.array([k1, k2, -p2, p1, k3])
        R[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    return K2, d2, R


@pytest.mark.parametrize("photo", ["choriginal", "chocclusion_original"])
@pytest.mark.parametrize("clockwise", [True, False], ids=["cw", "ccw"])
def test_portrait_photo_with_portrait_intrinsics(ref: Ref, photo: str, clockwise: bool
                                                 ) -> None:
    img = ref.photos[photo]
    im = cv2.rotate(img, cv2.ROTATE_90_CLOCKWISE if clockwise
                    else cv2.ROTATE_90_COUNTERCLOCKWISE)
    K2, d2, R = _rotated_camera(ref.K, ref.dist, *img.shape[:2], clockwise)
    _check(ref, photo, im, K2, d2, 0.001, 0.001, R=R)


@pytest.mark.parametrize("orientation", [6, 8, 3])
def test_jpeg_exif_orientation_is_applied(ref: Ref, tmp_path: Path, orientation: int
                                          ) -> None:
    """A phone stores a portrait photo landscape with an EXIF tag: it is read upright."""
    from PIL import Image

    img = ref.photos["choriginal"]
    # the stored pixels: the upright photo turned the other way than the tag undoes
    stored = {6: cv2.rotate(img, cv2.ROTATE_90_COUNTERCLOCKWISE),
              8: cv2.rotate(img, cv2.ROTATE_90_CLOCKWISE),
              3: cv2.rotate(img, cv2.ROTATE_180)}[orientation]
    p = tmp_path / "phone.jpg"
    exif = Image.Exif()
    exif[0x0112] = orientation
    Image.fromarray(stored).save(p, quality=98, exif=exif)
    got = load_image(p)
    assert got.shape == img.shape
    _check(ref, "choriginal", got, ref.K, ref.dist, 0.5, 0.1)


# ------------------------------------------------------------------ files and colour


def test_grey_png_16bit_and_alpha_photos(ref: Ref, tmp_path: Path) -> None:
    img = ref.photos["choriginal"]
    grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    cases = {"rgb.png": cv2.cvtColor(img, cv2.COLOR_RGB2BGR),
             "grey.png": grey,
             "grey16.png": grey.astype(np.uint16) * 257,
             "rgb16.tiff": cv2.cvtColor(img, cv2.COLOR_RGB2BGR).astype(np.uint16) * 257,
             "alpha.png": cv2.cvtColor(img, cv2.COLOR_RGB2BGRA)}
    for name, arr in cases.items():
        p = tmp_path / name
        assert cv2.imwrite(str(p), arr)
        got = load_image(p)
        assert got.dtype == np.uint8 and got.shape[:2] == img.shape[:2], name
        assert (got.ndim == 2) == name.startswith("grey"), name
        _check(ref, "choriginal", got, ref.K, ref.dist, 0.001, 0.001)
    # a grey JPEG: recompressed
    p = tmp_path / "grey.jpg"
    cv2.imwrite(str(p), grey, [cv2.IMWRITE_JPEG_QUALITY, 95])
    _check(ref, "choriginal", load_image(p), ref.K, ref.dist, 0.5, 0.1)
    # and in memory: a 16-bit array is scaled, not clipped to white
    _check(ref, "choriginal", grey.astype(np.uint16) * 257, ref.K, ref.dist, 0.001, 0.001)


def test_bad_photo_files(tmp_path: Path) -> None:
    p = tmp_path / "a.gif"
    p.write_bytes(b"GIF89a")
    with pytest.raises(InputError, match="unsupported photo type"):
        load_image(p)
    p = tmp_path / "broken.jpg"
    p.write_bytes(b"\xff\xd8\xff\xe0 not really")
    with pytest.raises(InputError, match="not a readable image"):
        load_image(p)
    with pytest.raises(InputError, match="no such file"):
        load_image(tmp_path / "missing.png")


# ----------------------------------------------------------------------- the lens


def _through_lens(img: np.ndarray, K: np.ndarray, d0: np.ndarray, d1: np.ndarray
                  ) -> np.ndarray:
    """The photo as a camera with the same K and distortion ``d1`` would take it."""
    h, w = img.shape[:2]
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    px = np.stack([u.ravel(), v.ravel()], 1).reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)
    xn = cv2.undistortPoints(px, K, d1, criteria=crit).reshape(-1, 2)
    src, _ = cv2.projectPoints(np.column_stack([xn, np.ones(len(xn))]), np.zeros(3),
                               np.zeros(3), K, d0)
    m = src.reshape(h, w, 2).astype(np.float32)
    return cv2.remap(img, m[..., 0], m[..., 1], cv2.INTER_CUBIC,
                     borderValue=(255, 255, 255))


@pytest.mark.parametrize("lens", [[-0.35, 0.12, 0, 0, 0], [-0.5, 0.3, 0.002, -0.001, -0.1],
                                  [0.3, 0.1, 0, 0, 0]], ids=["barrel", "barrel_tang",
                                                             "pincushion"])
def test_strong_distortion_with_its_coefficients(ref: Ref, lens: list[float]) -> None:
    """Markers found in the undistorted image (K and dist given to detect_markers), corners
    returned in the photo's pixels: every marker, board pose within 0.1 mm / 0.06° (the
    pattern fit on the bent markers alone: 16 markers, 0.11 mm / 0.16°)."""
    d1 = np.array(lens)
    im = _through_lens(ref.photos["choriginal"], ref.K, ref.dist, d1)
    ds = detect_markers(im, DICT, K=ref.K, dist=d1)
    assert ds.ids == ALL_IDS
    dt, dr = pose_diff(board_pose(ds, ref.K, d1), ref.poses["choriginal"])
    assert dt < 0.5 and dr < 0.1, (dt, dr)
    # the same corners with the photo's own (weaker) distortion: centimetres off, so the
    # coefficients given are the ones that count
    dt, dr = pose_diff(board_pose(ds, ref.K, ref.dist), ref.poses["choriginal"])
    assert dt > 5.0


def test_undistorted_detection_keeps_the_photo_pixels(ref: Ref) -> None:
    """With the photo's own lens the corners found through undistortion are where the
    plain detection puts them (sub-pixel) and the board pose agrees."""
    img = ref.photos["choriginal"]
    plain = detect_markers(img, DICT)
    lens = detect_markers(img, DICT, K=ref.K, dist=ref.dist)
    assert lens.ids == plain.ids
    worst = max(float(np.abs(a.corners_px - b.corners_px).max())
                for a, b in zip(lens.markers, plain.markers, strict=True))
    assert worst < 0.5
    dt, dr = pose_diff(board_pose(lens, ref.K, ref.dist), ref.poses["choriginal"])
    assert dt < 0.5 and dr < 0.1


# ------------------------------------------------------------------- dictionaries


@pytest.mark.parametrize("configured", ["DICT_4X4_50", "DICT_5X5_100", "apriltag_36h11"])
def test_wrong_dictionary_is_named(ref: Ref, configured: str) -> None:
    img = ref.photos["choriginal"]
    assert detect_markers(img, configured).ids == []
    with pytest.raises(InputError, match=f"set the dictionary to {DICT}"):
        detect_markers(img, configured, require=True)


def test_no_markers_at_all_and_find_dictionary(ref: Ref) -> None:
    blank = np.full((480, 640), 200, np.uint8)
    with pytest.raises(InputError, match="check that the markers are in view"):
        detect_markers(blank, DICT, require=True)
    assert find_dictionary(blank) is None
    found = find_dictionary(ref.photos["chocclusion_original"])
    assert found == (DICT, len(OCCLUDED_IDS))


def test_calibration_with_the_wrong_dictionary_names_the_printed_one() -> None:
    """The simulated room's 4×4 markers calibrated as 6×6: no sensor sees a marker, and
    the error says which dictionary they were printed from (not 'no chain to marker 1')."""
    from engine.calibration.pipeline import calibrate_frames
    from engine.calibration.simcapture import render_sensor_frames
    from engine.errors import CalibrationError
    from engine.sim.rig import default_avenue_rig

    rig = default_avenue_rig(0)
    frames = [render_sensor_frames(rig.sensor("S1"), rig, 2, None)]
    with pytest.raises(CalibrationError, match="set the dictionary to DICT_4X4_50"):
        calibrate_frames(frames, 0.2, dictionary="6x6_250", icp=False)
