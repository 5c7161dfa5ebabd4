"""Depth unprojection through a lens: the per-camera table of undistorted rays against
OpenCV (``cv2.undistortPoints`` iterated to convergence, ``cv2.projectPoints`` back), and
``depth_to_points(..., dist=...)`` against a plane seen through the lens."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from engine.errors import InputError
from engine.pointcloud import (
    CameraIntrinsics,
    depth_to_points,
    pixel_ray_table,
    undistort_normalised,
)

#: an Azure Kinect NFOV depth camera's kind of lens: OpenCV rational model (k4-k6)
K4A = CameraIntrinsics(320, 288, 252.0, 252.1, 160.5, 166.7,
                       (0.45, 0.12, 6e-5, -4e-5, 0.003, 0.78, 0.25, 0.01))
#: Brown-Conrady barrel lens with tangential and thin-prism terms
BARREL = CameraIntrinsics(256, 212, 182.0, 182.5, 127.0, 104.3,
                          (-0.12, 0.03, 0.0008, -0.0005, -0.004, 0.0, 0.0, 0.0,
                           0.001, -0.0005, 0.0007, 0.0002))


def _grid(intr: CameraIntrinsics) -> np.ndarray:
    u, v = np.meshgrid(np.arange(intr.width, dtype=float), np.arange(intr.height, dtype=float))
    return np.stack([u.ravel(), v.ravel()], axis=1)


@pytest.mark.parametrize("intr", [K4A, BARREL], ids=["k4a_rational", "barrel_prism"])
def test_ray_table_is_opencvs_undistortion(intr: CameraIntrinsics) -> None:
    table = pixel_ray_table(intr)
    assert table.shape == (intr.height, intr.width, 2) and np.isfinite(table).all()
    px = _grid(intr)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 300, 1e-15)
    ref = cv2.undistortPoints(px.reshape(-1, 1, 2), intr.K, intr.dist_array, None, None,
                              None, crit).reshape(-1, 2)
    assert np.abs(table.reshape(-1, 2) - ref).max() < 1e-9
    # OpenCV's default (5 fixed-point steps) is what the table must not be content with
    rough = cv2.undistortPoints(px.reshape(-1, 1, 2), intr.K, intr.dist_array).reshape(-1, 2)
    assert np.abs(rough - ref).max() * intr.fx > 1e-3
    # and it bends: far from the centre the pinhole's ray is centimetres off at 3 m
    pin = np.stack([(px[:, 0] - intr.cx) / intr.fx, (px[:, 1] - intr.cy) / intr.fy], 1)
    assert np.abs(table.reshape(-1, 2) - pin).max() * 3.0 > 0.05


@pytest.mark.parametrize("intr", [K4A, BARREL], ids=["k4a_rational", "barrel_prism"])
def test_ray_table_projects_back_onto_its_pixels(intr: CameraIntrinsics) -> None:
    table = pixel_ray_table(intr).reshape(-1, 2)
    obj = np.concatenate([table, np.ones((len(table), 1))], axis=1) * 2.5  # any depth
    uv, _ = cv2.projectPoints(obj.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), intr.K,
                              intr.dist_array)
    assert np.abs(uv.reshape(-1, 2) - _grid(intr)).max() < 1e-6


def test_table_is_cached_per_camera_and_pinhole_without_lens() -> None:
    assert pixel_ray_table(K4A) is pixel_ray_table(K4A)
    pin = CameraIntrinsics(K4A.width, K4A.height, K4A.fx, K4A.fy, K4A.cx, K4A.cy)
    t = pixel_ray_table(pin)
    assert t is not pixel_ray_table(K4A)
    assert t[5, 7, 0] == pytest.approx((7 - K4A.cx) / K4A.fx)
    assert t[5, 7, 1] == pytest.approx((5 - K4A.cy) / K4A.fy)
    # an explicit lens argument overrides the intrinsics' own; zeros are a pinhole
    assert np.array_equal(pixel_ray_table(K4A, ()), t)
    assert np.array_equal(pixel_ray_table(pin, np.zeros(5)), t)
    assert np.array_equal(pixel_ray_table(pin, K4A.dist), pixel_ray_table(K4A))
    with pytest.raises(ValueError):
        t[0, 0, 0] = 1.0  # shared: read-only
    # another image size (a downscaled frame) is another table
    half = CameraIntrinsics(160, 144, K4A.fx / 2, K4A.fy / 2, K4A.cx / 2, K4A.cy / 2, K4A.dist)
    assert pixel_ray_table(half).shape == (144, 160, 2)


def test_pixels_past_the_fold_of_the_lens_have_no_ray() -> None:
    """A strong barrel model turns back beyond some radius: pixels there have no
    solution (or only one on the far side of the fold) and get NaN; the rest are exact."""
    wide = CameraIntrinsics(200, 200, 150.0, 150.0, 99.5, 99.5, (-0.35, 0.0, 0.0, 0.0))
    t = pixel_ray_table(wide)
    bad = ~np.isfinite(t[..., 0])
    assert bad[0, 0] and not bad[100, 100] and 0 < bad.sum() < bad.size / 2
    # r_d = r (1 - 0.35 r²) peaks at r = 1/sqrt(1.05) (r_d 0.65): pixels beyond have none
    rd = np.hypot(*((_grid(wide) - 99.5) / 150.0).T).reshape(200, 200)
    assert not bad[rd < 0.63].any() and bad[rd > 0.66].all()
    ok = t[~bad]
    uv, _ = cv2.projectPoints(np.concatenate([ok, np.ones((len(ok), 1))], 1).reshape(-1, 1, 3),
                              np.zeros(3), np.zeros(3), wide.K, wide.dist_array)
    assert np.abs(uv.reshape(-1, 2) - _grid(wide)[(~bad).ravel()]).max() < 1e-6


def test_bad_lenses_are_refused_with_what_to_give() -> None:
    with pytest.raises(InputError, match="4, 5, 8, 12 or 14"):
        pixel_ray_table(K4A, (0.1, 0.2, 0.3))
    with pytest.raises(InputError, match="finite"):
        pixel_ray_table(K4A, (0.1, np.nan, 0.0, 0.0))
    with pytest.raises(InputError, match="tilted"):
        pixel_ray_table(K4A, (0.1,) + (0.0,) * 11 + (0.01, 0.0))
    with pytest.raises(InputError, match="positive focal"):
        pixel_ray_table(CameraIntrinsics(10, 10, 0.0, 1.0, 5.0, 5.0), (0.1, 0, 0, 0))
    # 14 coefficients without tilt are fine
    assert np.isfinite(undistort_normalised([[3.0, 4.0]], K4A, (0.1,) + (0.0,) * 13)).all()


def _plane_depth(intr: CameraIntrinsics, n: np.ndarray, d: float) -> np.ndarray:
    """Depth (z, metres) of the plane ``n·p = d`` for every pixel of a camera with a
    lens, from OpenCV's own undistortion (independent of the table)."""
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 300, 1e-15)
    r = cv2.undistortPoints(_grid(intr).reshape(-1, 1, 2), intr.K, intr.dist_array, None,
                            None, None, crit).reshape(-1, 2)
    rays = np.concatenate([r, np.ones((len(r), 1))], axis=1)
    return (d / (rays @ n)).reshape(intr.height, intr.width)


def test_depth_to_points_puts_a_plane_seen_through_the_lens_on_the_plane() -> None:
    n = np.array([0.1, -0.2, 1.0])
    n /= np.linalg.norm(n)
    depth = _plane_depth(K4A, n, 2.5)
    depth[10:20, 30:40] = 0.0  # no return
    pts, flat = depth_to_points(depth, K4A, 1.0, dist=K4A.dist)
    assert len(pts) == depth.size - 100
    assert np.abs(pts @ n - 2.5).max() < 1e-9
    assert np.allclose(pts[:, 2], depth.ravel()[flat])
    # without the lens (the default) the same image is a bowl, centimetres off the plane
    pin, flat_pin = depth_to_points(depth, K4A, 1.0)
    assert np.array_equal(flat, flat_pin)
    assert np.abs(pin @ n - 2.5).max() > 0.05
    # strides take the table's pixels
    sub, flat_s = depth_to_points(depth, K4A, 1.0, stride=3, dist=K4A.dist)
    assert np.abs(sub @ n - 2.5).max() < 1e-9
    assert set(flat_s.tolist()) <= set(flat.tolist())
    assert np.all((flat_s % K4A.width) % 3 == 0) and np.all((flat_s // K4A.width) % 3 == 0)


def test_depth_to_points_drops_pixels_without_a_ray() -> None:
    wide = CameraIntrinsics(200, 200, 150.0, 150.0, 99.5, 99.5, (-0.35, 0.0, 0.0, 0.0))
    depth = np.full((200, 200), 2000, np.uint16)
    pts, flat = depth_to_points(depth, wide, 1000.0, dist=wide.dist)
    valid = np.isfinite(pixel_ray_table(wide)[..., 0]).ravel()
    assert len(pts) == valid.sum() and valid[flat].all() and np.isfinite(pts).all()


def test_simulated_depth_lens_reaches_the_calibration() -> None:
    """The simulator renders depth through a lens (``SensorRenderer(depth_dist=...)``) and
    its capture frames carry it, as a node sends it: the calibration then unprojects the
    markers' depth along the lens's rays (S1, S2 within 3.5 mm / 0.07°); given as a
    pinhole the same frames put both sensors 6 cm / 1.2° off."""
    from dataclasses import replace

    from engine.calibration.pipeline import calibrate_frames
    from engine.calibration.simcapture import CAPTURE_COLOR_SIZE, render_sensor_frames
    from engine.geometry import pose_error
    from engine.sim.render import SensorRenderer
    from engine.sim.rig import default_avenue_rig

    lens = (-0.12, 0.03, 0.0008, -0.0005, 0.0)
    rig = default_avenue_rig(0)
    rng = np.random.default_rng(2)
    frames = [render_sensor_frames(rig.sensor(s), rig, 3, rng, renderer=SensorRenderer(
        rig.sensor(s), rig, CAPTURE_COLOR_SIZE, depth_dist=lens)) for s in ("S1", "S2")]
    assert all(isinstance(f.depth_intrinsics, CameraIntrinsics)
               and f.depth_intrinsics.dist == lens for f in frames)
    sizes = {m.id: m.size_m for m in rig.markers}
    res = calibrate_frames(frames, sizes, icp=False)
    assert res.meta["cameras"]["S1"]["depth"]["dist"] == pytest.approx(lens)
    pin = calibrate_frames([replace(f, depth_intrinsics=f.depth_intrinsics.K)  # type: ignore[union-attr]
                            for f in frames], sizes, icp=False)
    for sid in ("S1", "S2"):
        truth = rig.sensor(sid).T_world_sensor
        dt, dr = pose_error(res.T_world_sensor[sid], truth)
        assert dt < 0.006 and np.degrees(dr) < 0.15, (sid, dt, np.degrees(dr))
        dt, dr = pose_error(pin.T_world_sensor[sid], truth)
        assert dt > 0.03 and np.degrees(dr) > 0.6, (sid, dt, np.degrees(dr))
