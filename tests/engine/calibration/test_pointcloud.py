"""Depth → (coloured) point clouds, projection and voxel downsampling."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import open3d as o3d
import pytest

from engine.errors import InputError
from engine.pointcloud import (
    CameraIntrinsics,
    depth_to_points,
    load_intrinsics_json,
    project_points,
    rgbd_to_colored_points,
    voxel_downsample,
)

RGBD = "rgbd/open3d"


def test_unproject_then_project_roundtrip() -> None:
    intr = CameraIntrinsics(64, 48, 50.0, 52.0, 31.5, 23.5)
    rng = np.random.default_rng(1)
    depth = (rng.uniform(0.5, 3.0, (48, 64)) * 1000).astype(np.uint16)
    depth[0, :5] = 0
    pts, flat = depth_to_points(depth, intr, depth_scale=1000.0)
    assert len(pts) == 64 * 48 - 5
    uv = project_points(pts, intr)
    assert np.allclose(uv[:, 0], flat % 64) and np.allclose(uv[:, 1], flat // 64)
    assert np.allclose(pts[:, 2], depth.ravel()[flat] / 1000.0)
    with pytest.raises(InputError, match="intrinsics are for"):
        depth_to_points(depth[:, :10], intr)


def test_voxel_downsample_averages() -> None:
    p = np.array([[0.01, 0.01, 0.01], [0.03, 0.03, 0.03], [0.51, 0.0, 0.0]])
    c = np.array([[0, 0, 0], [100, 200, 50], [9, 9, 9]], np.uint8)
    out, oc = voxel_downsample(p, 0.1, c)
    assert oc is not None
    order = np.argsort(out[:, 0])
    assert np.allclose(out[order[0]], [0.02, 0.02, 0.02])
    assert oc[order[0]].tolist() == [50, 100, 25]
    assert len(out) == 2
    with pytest.raises(InputError):
        voxel_downsample(p, 0.0)


def test_real_rgbd_frame_to_coloured_cloud(shared_data: Path) -> None:
    """The Open3D PrimeSense frame with its intrinsics matches Open3D's own unprojection."""
    d = shared_data / RGBD
    intr = load_intrinsics_json(d / "camera_primesense.json")
    assert (intr.width, intr.height, intr.fx, intr.cx) == (640, 480, 525.0, 319.5)
    color = cv2.cvtColor(cv2.imread(str(d / "RGBD_color_00000.jpg")), cv2.COLOR_BGR2RGB)
    depth = cv2.imread(str(d / "RGBD_depth_00000.png"), cv2.IMREAD_UNCHANGED)
    pts, cols = rgbd_to_colored_points(color, depth, intr, depth_scale=1000.0, max_depth=3.0)
    assert pts.shape[0] == cols.shape[0] > 100_000
    # the same frame through Open3D
    rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
        o3d.geometry.Image(np.ascontiguousarray(color)), o3d.geometry.Image(depth),
        depth_scale=1000.0, depth_trunc=3.0, convert_rgb_to_intensity=False)
    pin = o3d.camera.PinholeCameraIntrinsic(640, 480, 525.0, 525.0, 319.5, 239.5)
    ref = o3d.geometry.PointCloud.create_from_rgbd_image(rgbd, pin)
    ref_pts = np.asarray(ref.points)
    assert abs(len(ref_pts) - len(pts)) <= 0.001 * len(pts)
    assert np.allclose(np.sort(pts[:, 2])[::1000], np.sort(ref_pts[:, 2])[::1000], atol=1e-3)
    ref_cols = np.asarray(ref.colors) * 255
    assert np.abs(cols.mean(0) - ref_cols.mean(0)).max() < 1.0
    small, sc = voxel_downsample(pts, 0.02, cols)
    assert sc is not None and 1000 < len(small) < len(pts) / 5
