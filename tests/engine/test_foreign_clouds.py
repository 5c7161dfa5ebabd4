"""Point clouds, depth images and intrinsics as other labs and devices write them.

The real clouds (``rgbd/pcl/bun0.pcd``: PCL's bunny with normals; ``rgbd/open3d/
Feature_cloud_bin_*.pcd``: two overlapping scans with colour), the real PrimeSense depth
frame and its intrinsics are rewritten here in other encodings (PLY ascii/binary, float/
double, big-endian; PCD ascii/binary/binary_compressed with 4- and 8-byte fields), other
origins (5 km away, as georeferenced or survey frames are), depth units (mm PNG, metres
float TIFF, RealSense L515's 0.25 mm) and intrinsics layouts (Open3D JSON, RealSense-style
JSON, ROS camera_info YAML in its ROS 1 and ROS 2 forms, OpenCV YAML). Each must give the
same cloud (bit-exact for doubles, float32 rounding otherwise), the same registration
(within 1 mm / 0.01°) or a typed error saying what to pass.

Our own writers are used: Open3D's writers round (ascii PLY keeps 7 digits: 5 mm at 5 km)
and write PCD only as float32.
"""

from __future__ import annotations

import struct
from pathlib import Path

import cv2
import numpy as np
import open3d as o3d
import pytest

from engine.calibration.icp import icp_align
from engine.errors import InputError
from engine.geometry import invert_transform, make_transform, pose_error, so3_exp
from engine.pointcloud import (
    depth_to_points,
    load_depth_image,
    load_intrinsics,
    load_intrinsics_json,
    load_point_cloud,
)

RGBD = "rgbd/open3d"
FAR = np.array([5000.25, -3200.5, 120.0])  # 5 km out: float32 steps of 0.49 mm


@pytest.fixture(scope="module")
def bunny(shared_data: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The bunny's points and normals (float32 in the file: exact in float64) and colours."""
    pc = o3d.io.read_point_cloud(shared_data / "rgbd/pcl/bun0.pcd")
    pts = np.asarray(pc.points)
    colors = np.random.default_rng(0).integers(0, 256, (len(pts), 3)).astype(np.uint8)
    return pts, np.asarray(pc.normals), colors


# ------------------------------------------------------------------------- writers


def _lzf_literals(b: bytes) -> bytes:
    """A valid LZF stream made of literal runs only (PCL's reader accepts any LZF)."""
    return b"".join(bytes([len(b[i:i + 32]) - 1]) + b[i:i + 32] for i in range(0, len(b), 32))


def write_ply(path: Path, pts: np.ndarray, colors: np.ndarray | None = None,
              normals: np.ndarray | None = None, *, binary: bool = False,
              double: bool = False, endian: str = "<") -> Path:
    f = "f8" if double else "f4"
    fields = [(a, f) for a in "xyz"]
    fields += [(f"n{a}", f) for a in "xyz"] if normals is not None else []
    fields += [(c, "u1") for c in ("red", "green", "blue")] if colors is not None else []
    ptype = {"f8": "double", "f4": "float", "u1": "uchar"}
    fmt = ("binary_little_endian" if endian == "<" else "binary_big_endian") if binary \
        else "ascii"
    head = ["ply", f"format {fmt} 1.0", "comment another lab's scanner",
            f"element vertex {len(pts)}", *(f"property {ptype[t]} {n}" for n, t in fields),
            "end_header"]
    cols = [pts[:, k] for k in range(3)]
    cols += [normals[:, k] for k in range(3)] if normals is not None else []
    cols += [colors[:, k] for k in range(3)] if colors is not None else []
    with path.open("wb") as fh:
        fh.write(("\n".join(head) + "\n").encode())
        if binary:
            rec = np.zeros(len(pts), dtype=[(n, endian + t) for n, t in fields])
            for (n, _), c in zip(fields, cols, strict=True):
                rec[n] = c
            fh.write(rec.tobytes())
        else:
            num = repr if double else (lambda v: f"{np.float32(v):.9g}")
            for i in range(len(pts)):
                row = [num(float(c[i])) if c.dtype.kind == "f" else str(int(c[i]))
                       for c in cols]
                fh.write((" ".join(row) + "\n").encode())
    return path


def write_pcd(path: Path, pts: np.ndarray, colors: np.ndarray | None = None,
              normals: np.ndarray | None = None, *, data: str = "ascii",
              double: bool = False, nan_rows: int = 0, float_rgb: bool = False) -> Path:
    """``float_rgb``: the packed colour typed ``F 4`` (PCL's default), else ``U 4``."""
    f = "f8" if double else "f4"
    fields = [(a, f) for a in "xyz"]
    fields += [(f"normal_{a}", f) for a in "xyz"] if normals is not None else []
    fields += [("rgb", "f4" if float_rgb else "u4")] if colors is not None else []
    n = len(pts) + nan_rows
    P = np.vstack([pts, np.full((nan_rows, 3), np.nan)])  # an organised cloud's holes
    cols = [P[:, k] for k in range(3)]
    if normals is not None:
        N = np.vstack([normals, np.zeros((nan_rows, 3))])
        cols += [N[:, k] for k in range(3)]
    if colors is not None:
        C = np.vstack([colors, np.zeros((nan_rows, 3), np.uint8)]).astype(np.uint32)
        packed = (C[:, 0] << 16) | (C[:, 1] << 8) | C[:, 2]
        cols.append(packed.view(np.float32) if float_rgb else packed)
    head = ["# .PCD v0.7 - Point Cloud Data file format", "VERSION 0.7",
            "FIELDS " + " ".join(n_ for n_, _ in fields),
            "SIZE " + " ".join(t[1] for _, t in fields),
            "TYPE " + " ".join("F" if t[0] == "f" else "U" for _, t in fields),
            "COUNT " + " ".join("1" for _ in fields), f"WIDTH {n}", "HEIGHT 1",
            "VIEWPOINT 0 0 0 1 0 0 0", f"POINTS {n}", f"DATA {data}"]
    with path.open("wb") as fh:
        fh.write(("\n".join(head) + "\n").encode())
        if data == "ascii":
            num = repr if double else (lambda v: f"{np.float32(v):.9g}")
            for i in range(n):
                fh.write((" ".join(num(float(c[i])) if c.dtype.kind == "f" else str(int(c[i]))
                                   for c in cols) + "\n").encode())
            return path
        rec = np.zeros(n, dtype=[(n_, "<" + t) for n_, t in fields])
        for (n_, _), c in zip(fields, cols, strict=True):
            rec[n_] = c
        if data == "binary":
            fh.write(rec.tobytes())
        else:  # binary_compressed: field-major, LZF
            raw = b"".join(rec[n_].tobytes() for n_, _ in fields)
            comp = _lzf_literals(raw)
            fh.write(struct.pack("<II", len(comp), len(raw)) + comp)
    return path


# ------------------------------------------------------------------------- clouds

CLOUDS = {
    "ply_ascii_float": dict(ext="ply", binary=False, double=False),
    "ply_ascii_double": dict(ext="ply", binary=False, double=True),
    "ply_binary_float": dict(ext="ply", binary=True, double=False),
    "ply_binary_double": dict(ext="ply", binary=True, double=True),
    "ply_binary_big_endian_double": dict(ext="ply", binary=True, double=True, endian=">"),
    "pcd_ascii_float": dict(ext="pcd", data="ascii", double=False),
    "pcd_ascii_double": dict(ext="pcd", data="ascii", double=True),
    "pcd_binary_float": dict(ext="pcd", data="binary", double=False),
    "pcd_binary_double": dict(ext="pcd", data="binary", double=True),
    "pcd_compressed_float": dict(ext="pcd", data="binary_compressed", double=False),
    "pcd_compressed_double": dict(ext="pcd", data="binary_compressed", double=True),
    "pcd_ascii_float_rgb": dict(ext="pcd", data="ascii", double=False, float_rgb=True),
    "pcd_binary_float_rgb": dict(ext="pcd", data="binary", double=True, float_rgb=True),
}


@pytest.mark.parametrize("far", [False, True], ids=["origin", "5km"])
@pytest.mark.parametrize("extras", ["plain", "colour_normals"])
@pytest.mark.parametrize("name", sorted(CLOUDS))
def test_cloud_encodings_read_the_same_points(bunny: tuple[np.ndarray, ...], tmp_path: Path,
                                              name: str, extras: str, far: bool) -> None:
    pts, normals, colors = bunny
    src = pts + FAR if far else pts
    kw = dict(CLOUDS[name])
    ext = kw.pop("ext")
    with_extras = extras == "colour_normals"
    c, n = (colors, normals) if with_extras else (None, None)
    path = tmp_path / f"{name}.{ext}"
    if ext == "ply":
        write_ply(path, src, c, n, **kw)
    else:
        write_pcd(path, src, c, n, nan_rows=4, **kw)
    got = load_point_cloud(path)
    if kw["double"]:
        assert np.array_equal(got.points, src)  # bit-exact: 5 km keeps every digit
    else:
        # float32 in the file: within one float32 step of each coordinate, nothing worse
        step = np.spacing(np.abs(src).astype(np.float32)).astype(np.float64)
        assert np.all(np.abs(got.points - src) <= step)
    assert got.meta["coordinate_type"] == ("float64" if kw["double"] else "float32")
    flagged = any("32-bit floats" in w for w in got.warnings)
    assert flagged == (far and not kw["double"]), got.warnings
    if with_extras:
        assert got.colors is not None and np.array_equal(got.colors, colors)
        assert got.normals is not None and np.allclose(got.normals, normals, atol=1e-6)
    else:
        assert got.colors is None and got.normals is None
    if ext == "pcd":
        assert got.meta["dropped"] == 4 and any("dropped" in w for w in got.warnings)


def test_open3d_compressed_pcd_with_back_references(shared_data: Path, tmp_path: Path
                                                    ) -> None:
    """Open3D's own binary_compressed writer (real LZF back references) reads the same."""
    pc = o3d.io.read_point_cloud(shared_data / RGBD / "Feature_cloud_bin_0.pcd")
    path = tmp_path / "o3d.pcd"
    o3d.io.write_point_cloud(path, pc, compressed=True)
    got = load_point_cloud(path)
    assert got.meta["encoding"] == "binary_compressed"
    assert np.array_equal(got.points, np.asarray(pc.points))
    assert got.colors is not None
    assert np.abs(got.colors - np.asarray(pc.colors) * 255).max() <= 0.5


def test_real_pcd_files_read_as_open3d_does(shared_data: Path) -> None:
    for rel in ("rgbd/pcl/bun0.pcd", f"{RGBD}/Feature_cloud_bin_1.pcd"):
        ref = o3d.io.read_point_cloud(shared_data / rel)
        got = load_point_cloud(shared_data / rel)
        assert np.array_equal(got.points, np.asarray(ref.points))
        assert got.normals is not None and np.allclose(got.normals, np.asarray(ref.normals))
        if ref.has_colors():  # the feature clouds' rgb is PCL's float-typed packed colour
            assert got.colors is not None
            assert np.abs(got.colors - np.asarray(ref.colors) * 255).max() <= 0.5


def test_bad_cloud_files_are_named(tmp_path: Path) -> None:
    cases = {"empty.pcd": b"", "text.ply": b"hello\n", "obj.obj": b"v 0 0 0\n",
             "noxyz.pcd": b"VERSION 0.7\nFIELDS a b\nSIZE 4 4\nTYPE F F\nCOUNT 1 1\n"
                          b"POINTS 1\nDATA ascii\n1 2\n",
             "short.pcd": b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
                          b"POINTS 10\nDATA binary\n" + bytes(12)}
    expect = {"empty.pcd": "empty", "text.ply": "not a PLY", "obj.obj": "use .ply",
              "noxyz.pcd": "lack x, y, z", "short.pcd": "truncated or damaged"}
    for name, content in cases.items():
        p = tmp_path / name
        p.write_bytes(content)
        with pytest.raises(InputError, match=expect[name]):
            load_point_cloud(p)
    with pytest.raises(InputError, match=r"no such file|cannot read"):
        load_point_cloud(tmp_path / "missing.ply")


# ------------------------------------------------------------------- registration


@pytest.fixture(scope="module")
def feature_clouds(shared_data: Path) -> tuple[np.ndarray, np.ndarray]:
    d = shared_data / RGBD
    return (np.asarray(o3d.io.read_point_cloud(d / "Feature_cloud_bin_0.pcd").points),
            np.asarray(o3d.io.read_point_cloud(d / "Feature_cloud_bin_1.pcd").points))


@pytest.mark.parametrize("double", [True, False], ids=["double", "float32"])
def test_registration_5km_from_the_origin(feature_clouds: tuple[np.ndarray, np.ndarray],
                                          tmp_path: Path, double: bool) -> None:
    """The two real scans 5 km out (in a file) register as they do at the origin.

    Open3D's normals and ICP fail on raw coordinates 1 km out (fitness 0 before the fix
    in ``icp_align``); with doubles the result is the origin's to nanometres, with float32
    coordinates (0.49 mm steps) within 1 mm / 0.01°.
    """
    src, dst = feature_clouds
    P = make_transform(so3_exp(np.radians([1.5, -1.0, 2.0])), [0.03, -0.02, 0.01])
    ref = icp_align(src, dst, P, voxel=0.02, max_dist=0.08)
    assert ref.fitness > 0.7
    S = make_transform(np.eye(3), FAR)
    fs = write_pcd(tmp_path / "s.pcd", src + FAR, data="binary", double=double)
    fd = write_ply(tmp_path / "d.ply", dst + FAR, binary=True, double=double)
    s, d = load_point_cloud(fs).points, load_point_cloud(fd).points
    far = icp_align(s, d, S @ P @ invert_transform(S), voxel=0.02, max_dist=0.08)
    dt, dr = pose_error(invert_transform(S) @ far.T @ S, ref.T)
    assert far.fitness == pytest.approx(ref.fitness, abs=0.01)
    assert dt < (1e-6 if double else 1e-3) and np.degrees(dr) < (1e-6 if double else 0.01)


# ------------------------------------------------------------------------- depth


@pytest.fixture(scope="module")
def depth_frame(shared_data: Path) -> tuple[np.ndarray, np.ndarray]:
    d = shared_data / RGBD
    intr = load_intrinsics_json(d / "camera_primesense.json")
    raw = cv2.imread(str(d / "RGBD_depth_00000.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16
    pts, _ = depth_to_points(raw, intr, 1000.0)
    return raw, pts


def _write_depth(tmp_path: Path, kind: str, raw: np.ndarray) -> tuple[Path, float | None]:
    """A depth variant of the mm frame and the depth_scale to pass (None: default)."""
    if kind == "png_mm":
        p = tmp_path / "d.png"
        cv2.imwrite(str(p), raw)
        return p, None
    if kind == "tiff_mm_uint16":
        p = tmp_path / "d.tiff"
        cv2.imwrite(str(p), raw)
        return p, None
    if kind == "tiff_float_m":
        p = tmp_path / "d.tiff"
        cv2.imwrite(str(p), raw.astype(np.float32) / 1000.0)
        return p, None
    if kind == "tiff_float_mm":
        p = tmp_path / "d.tiff"
        cv2.imwrite(str(p), raw.astype(np.float32))
        return p, 1000.0
    if kind == "png_l515_quarter_mm":
        p = tmp_path / "d.png"
        cv2.imwrite(str(p), (raw.astype(np.uint32) * 4).astype(np.uint16))
        return p, 4000.0
    raise AssertionError(kind)


@pytest.mark.parametrize("kind", ["png_mm", "tiff_mm_uint16", "tiff_float_m", "tiff_float_mm",
                                  "png_l515_quarter_mm"])
def test_depth_units_give_the_same_cloud(depth_frame: tuple[np.ndarray, np.ndarray],
                                         shared_data: Path, tmp_path: Path, kind: str) -> None:
    raw, ref = depth_frame
    path, scale = _write_depth(tmp_path, kind, raw)
    depth, used = load_depth_image(path, depth_scale=scale)
    intr = load_intrinsics(shared_data / RGBD / "camera_primesense.json")
    pts, _ = depth_to_points(depth, intr, 1.0)
    assert pts.shape == ref.shape
    assert np.abs(pts - ref).max() < 1e-6  # float32 metres: < 1 µm
    assert used == (scale or (1.0 if "float_m" in kind else 1000.0))


def test_wrong_depth_scales_and_formats_are_named(depth_frame: tuple[np.ndarray, np.ndarray],
                                                  tmp_path: Path) -> None:
    raw, _ = depth_frame
    # the L515's quarter millimetres read as millimetres: 4x too far. A scene 2.5 m
    # further away (median 4.4 m: 17 m read as mm) is refused with the scale; this near
    # one (1.9 m -> 7.4 m) cannot be told from a far room, hence depth_scale
    p = tmp_path / "l515.png"
    far = np.where(raw > 0, raw.astype(np.uint32) + 2500, 0)
    cv2.imwrite(str(p), (far * 4).astype(np.uint16))
    with pytest.raises(InputError, match="depth_scale=4000"):
        load_depth_image(p)
    assert load_depth_image(p, depth_scale=4000)[0].max() == pytest.approx(
        (raw.max() + 2500) / 1000)
    # float millimetres taken for metres
    p = tmp_path / "mm.tiff"
    cv2.imwrite(str(p), raw.astype(np.float32))
    with pytest.raises(InputError, match="depth_scale=1000"):
        load_depth_image(p)
    p = tmp_path / "vis.png"
    cv2.imwrite(str(p), (raw // 40).astype(np.uint8))
    with pytest.raises(InputError, match="8-bit"):
        load_depth_image(p)
    p = tmp_path / "colour.png"
    cv2.imwrite(str(p), np.dstack([raw] * 3))
    with pytest.raises(InputError, match="colour image"):
        load_depth_image(p)
    p = tmp_path / "d.exr"
    p.write_bytes(b"v/1\x01" + bytes(100))
    with pytest.raises(InputError, match="TIFF"):
        load_depth_image(p)
    with pytest.raises(InputError, match="positive"):
        load_depth_image(tmp_path / "l515.png", depth_scale=0)


# -------------------------------------------------------------------- intrinsics

ROS1 = """image_width: 640
image_height: 480
camera_name: depth
camera_matrix:
  rows: 3
  cols: 3
  data: [525.0, 0.0, 319.5, 0.0, 525.0, 239.5, 0.0, 0.0, 1.0]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0.0, 0.0, 0.0, 0.0, 0.0]
"""
ROS2 = """header:
  frame_id: camera_depth_optical_frame
height: 480
width: 640
distortion_model: plumb_bob
d: [0.0, 0.0, 0.0, 0.0, 0.0]
k: [525.0, 0.0, 319.5, 0.0, 525.0, 239.5, 0.0, 0.0, 1.0]
"""
REALSENSE = ('{"width": 640, "height": 480, "ppx": 319.5, "ppy": 239.5, "fx": 525.0, '
             '"fy": 525.0, "model": "brown_conrady", "coeffs": [0, 0, 0, 0, 0]}')
OPENCV = """%YAML:1.0
---
image_width: 640
image_height: 480
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 525., 0., 319.5, 0., 525., 239.5, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ 0., 0., 0., 0., 0. ]
"""


@pytest.mark.parametrize(("name", "text"), [("ros1.yaml", ROS1), ("ros2.yaml", ROS2),
                                            ("realsense.json", REALSENSE),
                                            ("opencv.yml", OPENCV)])
def test_intrinsics_layouts(shared_data: Path, tmp_path: Path, name: str, text: str) -> None:
    ref = load_intrinsics(shared_data / RGBD / "camera_primesense.json")
    p = tmp_path / name
    p.write_text(text)
    got = load_intrinsics(p)
    assert (got.width, got.height, got.fx, got.fy, got.cx, got.cy) == (
        ref.width, ref.height, ref.fx, ref.fy, ref.cx, ref.cy)
    assert np.allclose(got.dist_array, 0.0)


def test_real_opencv_calibration_yml_and_bad_intrinsics(shared_data: Path, tmp_path: Path
                                                        ) -> None:
    got = load_intrinsics(shared_data / "markers/charuco/tutorial_camera_charuco.yml")
    assert (got.width, got.height) == (640, 480)
    assert got.fx == pytest.approx(452.5107222) and len(got.dist) == 5
    p = tmp_path / "bad.json"
    p.write_text('{"focal": 500, "w": 640}')
    with pytest.raises(InputError, match=r"need fx, fy, cx, cy.*found keys \['focal', 'w'\]"):
        load_intrinsics(p)
    p = tmp_path / "cam.txt"
    p.write_text("525 525 319.5 239.5")
    with pytest.raises(InputError, match=r"Open3D \.json, a ROS camera_info \.yaml"):
        load_intrinsics(p)
