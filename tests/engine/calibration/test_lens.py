"""Lens distortion through the calibration: rendered by the simulator, given to marker
detection and to the corner rays, kept with the result; and on the real ChArUco photos
with their calibrated lens."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from engine.calibration.corners3d import corner_rays, detect_with_lens
from engine.calibration.detect import load_image
from engine.calibration.pipeline import calibrate_frames
from engine.calibration.simcapture import render_sensor_frames
from engine.errors import CalibrationError, InputError
from engine.geometry import pose_error
from engine.pointcloud import CameraIntrinsics
from engine.sim.render import SensorRenderer
from engine.sim.rig import default_avenue_rig
from tests.engine.calibration.test_graph_pipeline import _sizes

#: a moderate barrel lens (a wide colour camera): 15 px at the corners of 960×540
LENS = [-0.08, 0.02, 0.0005, -0.0003, 0.0]
_CRIT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)


def test_renderer_follows_the_lens_model() -> None:
    """A rendered lens image is the pinhole image seen through OpenCV's distortion model:
    remapping the pinhole rendering by ``projectPoints`` gives the distorted one."""
    rig = default_avenue_rig(0)
    s = rig.sensor("S1")
    size = (320, 180)
    pin = SensorRenderer(s, rig, size).render([], None).color
    bent = SensorRenderer(s, rig, size, color_dist=LENS).render([], None).color
    assert pin is not None and bent is not None
    K = s.model.color_intrinsics(*size)
    w, h = size
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    xn = cv2.undistortPoints(np.stack([u.ravel(), v.ravel()], 1).reshape(-1, 1, 2), K,
                             np.array(LENS), None, None, None, _CRIT).reshape(-1, 2)
    src = (xn * np.diag(K)[:2] + K[:2, 2]).reshape(h, w, 2).astype(np.float32)
    warped = cv2.remap(pin, src[..., 0], src[..., 1], cv2.INTER_LINEAR)
    inner = (slice(10, h - 10), slice(10, w - 10))
    diff = np.abs(warped[inner].astype(float) - bent[inner].astype(float))
    assert np.median(diff) < 2.0  # resampling of the pinhole image only
    assert np.abs(pin[inner].astype(float) - bent[inner].astype(float)).mean() > \
        2 * diff.mean()  # and the lens did change the picture
    with pytest.raises(InputError, match="color_dist"):
        SensorRenderer(s, rig, size, color_dist=[0.1, 0.2, 0.3])


def test_calibration_needs_the_lens_it_was_captured_with() -> None:
    """Rendered through a lens: with its distortion passed the poses are within the
    pipeline's tolerance (10 mm / 0.5°); with the pinhole K alone the 3D corners bend off
    their squares and the poses err by centimetres (S1, S2: 27 / 20 mm, 0.65° / 0.47°;
    passed: 3.4 / 1.5 mm) — or the markers are refused outright."""
    rig = default_avenue_rig(0)
    rng = np.random.default_rng(2)
    frames = [render_sensor_frames(rig.sensor(s), rig, 3, rng, color_dist=LENS)
              for s in ("S1", "S2")]
    assert all(isinstance(f.color_intrinsics, CameraIntrinsics)
               and np.allclose(f.color_intrinsics.dist, LENS) for f in frames)
    res = calibrate_frames(frames, _sizes(rig), icp=False)
    for sid in ("S1", "S2"):
        dt, dr = pose_error(res.T_world_sensor[sid], rig.sensor(sid).T_world_sensor)
        assert dt < 0.01 and np.degrees(dr) < 0.5, (sid, dt, np.degrees(dr))
    # the camera model is kept with the result (and saved with it: meta)
    assert res.meta["cameras"]["S1"]["color"]["dist"] == pytest.approx(LENS)
    assert res.meta["cameras"]["S1"]["depth"]["dist"] == []
    pinhole = [replace(f, color_intrinsics=np.asarray(f.color_intrinsics.K))  # type: ignore[union-attr]
               for f in frames]
    try:
        bad = calibrate_frames(pinhole, _sizes(rig), icp=False)
    except CalibrationError as exc:  # every marker off its square: refused, also a failure
        assert "miss its square" in str(exc)
        return
    errs = [pose_error(bad.T_world_sensor[s], rig.sensor(s).T_world_sensor)[0]
            for s in ("S1", "S2")]
    assert max(errs) > 0.015, errs


def test_depth_lens_unprojects_along_undistorted_rays() -> None:
    """A depth camera with distortion: the corner estimator's depth points lie on the
    undistorted rays (``corner_rays``), not the pinhole's."""
    K = np.array([[500.0, 0, 320], [0, 500, 288], [0, 0, 1]])
    intr = CameraIntrinsics.from_matrix(K, 640, 576, [0.1, -0.05, 0.0, 0.0, 0.0])
    px = np.array([[10.0, 10.0], [320.0, 288.0], [630.0, 560.0]])
    rays = corner_rays(px, intr)
    assert np.allclose(rays[1], [0.0, 0.0, 1.0])
    n = cv2.undistortPoints(px.reshape(-1, 1, 2), K, intr.dist_array, None, None, None,
                            _CRIT).reshape(-1, 2)
    assert np.allclose(rays[:, :2], n, atol=1e-9)
    pin = (px - K[:2, 2]) / 500.0
    assert np.abs(rays[[0, 2], :2] - pin[[0, 2]]).max() * 500 > 5  # pixels at the corners


def test_charuco_photo_lens_moves_corners_as_undistort_points_says(shared_data: Path) -> None:
    """The real ChArUco photo with its calibrated lens (``tutorial_camera_charuco.yml``):
    the pipeline's detection path finds the same markers, corners in the photo's own
    pixels (≤ 0.5 px from the plain detection), and the rays it fits on are
    ``cv2.undistortPoints`` of those corners: up to 0.9 px away from the pinhole rays."""
    d = shared_data / "markers/charuco"
    fs = cv2.FileStorage(str(d / "tutorial_camera_charuco.yml"), cv2.FILE_STORAGE_READ)
    K = fs.getNode("camera_matrix").mat()
    dist = fs.getNode("distortion_coefficients").mat().ravel()
    w, h = int(fs.getNode("image_width").real()), int(fs.getNode("image_height").real())
    img = load_image(d / "choriginal.jpg")
    pin_i = CameraIntrinsics.from_matrix(K, w, h)
    lens_i = CameraIntrinsics.from_matrix(K, w, h, dist)
    plain = detect_with_lens(img, pin_i, "DICT_6X6_250")
    lens = detect_with_lens(img, lens_i, "DICT_6X6_250")
    assert lens.ids == plain.ids == list(range(17))
    pp = np.concatenate([m.corners_px for m in plain.markers])
    pl = np.concatenate([m.corners_px for m in lens.markers])
    assert np.abs(pp - pl).max() < 0.5
    r_lens = corner_rays(pl, lens_i)[:, :2]
    r_pin = corner_rays(pp, pin_i)[:, :2]
    want = cv2.undistortPoints(pl.reshape(-1, 1, 2), K, dist, None, None, None,
                               _CRIT).reshape(-1, 2)
    assert np.abs(r_lens - want).max() * K[0, 0] < 1e-6
    moved_px = np.abs(r_lens - r_pin).max() * K[0, 0]
    assert 0.4 < moved_px < 2.0, moved_px


def test_icp_cloud_uses_the_depth_lens() -> None:
    """The ICP refinement's static cloud of a depth camera with a lens: each pixel's depth
    along its undistorted ray (the pinhole would put a flat wall's corners 9 mm off here)."""
    from engine.calibration.corners3d import SensorFrames
    from engine.calibration.pipeline import static_cloud

    K = np.array([[250.0, 0, 63.5], [0, 250.0, 47.5], [0, 0, 1]])
    dist = [0.2, -0.1, 0.0, 0.0, 0.0]
    depth = np.full((96, 128), 2000, np.uint16)
    colour = np.zeros((96, 128, 3), np.uint8)
    lens = SensorFrames("S1", [colour], [depth], CameraIntrinsics.from_matrix(K, 128, 96, dist),
                        K)
    pts = static_cloud(lens)
    pin = static_cloud(SensorFrames("S1", [colour], [depth], K, K))
    assert len(pts) == len(pin) > 0 and np.allclose(pts[:, 2], 2.0)
    px = np.column_stack([pin[:, 0] / 2.0 * 250 + 63.5, pin[:, 1] / 2.0 * 250 + 47.5])
    want = cv2.undistortPoints(px.reshape(-1, 1, 2), K, np.array(dist), None, None, None,
                               _CRIT).reshape(-1, 2) * 2.0
    assert np.allclose(pts[:, :2], want, atol=1e-9)
    assert np.abs(pts[:, :2] - pin[:, :2]).max() > 0.005  # metres at the image corners
