"""The live merged point cloud through a depth lens (an Azure Kinect's depth images are not
undistorted): a flat surface seen by two sensors with a strong lens is flat and the two
clouds meet when the lens is applied, and measurably not without it. The lens comes
from the active calibration's camera models (the calibration capture is where a node's
lens reaches the server); simulated nodes render their depth through it."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from app.server.streaming import DepthFrame
from app.viewer.cloud import DepthView, calibrated_depth_lens, merge_depth_views
from engine.coverage import sensor_pose
from engine.errors import InputError

#: strong barrel lens with tangential terms (8 % at the image corner)
LENS = (-0.12, 0.03, 0.0008, -0.0005, 0.0)


def _rays(K: np.ndarray, w: int, h: int, dist: tuple[float, ...]) -> np.ndarray:
    """Camera-frame rays (z = 1) of every pixel of a distorted image, by OpenCV (the ground
    truth here, independent of the live cloud's ray table)."""
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 300, 1e-15)
    n = cv2.undistortPoints(np.stack([u.ravel(), v.ravel()], 1).reshape(-1, 1, 2), K,
                            np.asarray(dist, float), None, None, None, crit).reshape(h, w, 2)
    return np.concatenate([n, np.ones((h, w, 1))], axis=-1)


def _wall_view(position: tuple[float, float, float], yaw_deg: float,
               dist: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Depth (uint16 mm) of the wall x = 3 m seen through the lens ``dist``."""
    w, h = 320, 288
    K = np.array([[230.0, 0.0, 159.5], [0.0, 230.0, 143.5], [0.0, 0.0, 1.0]])
    T = sensor_pose(position, yaw_deg, 0.0)
    d = _rays(K, w, h, dist) @ T[:3, :3].T  # world direction per unit camera z
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (3.0 - T[0, 3]) / d[..., 0]
    depth = np.where((z > 0.3) & (z < 8.0), np.round(z * 1000.0), 0).astype(np.uint16)
    return depth, K, T


def test_merged_wall_of_two_sensors_is_flat_only_with_the_lens() -> None:
    a = _wall_view((0.0, -0.6, 1.2), 12.0, LENS)
    b = _wall_view((0.2, 0.7, 1.0), -15.0, LENS)

    def merged(dist: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
        views = [DepthView(dep, K, T, col, dist=dist)
                 for (dep, K, T), col in ((a, (255, 0, 0)), (b, (0, 0, 255)))]
        return merge_depth_views(views, voxel_m=0.03)

    pts, cols = merged(LENS)
    off = np.abs(pts[:, 0] - 3.0)
    assert len(pts) > 1000 and off.max() < 0.01  # depth in whole millimetres, voxel means
    # both sensors' points share voxels where they overlap
    mixed = (cols[:, 0] > 0) & (cols[:, 2] > 0)
    assert mixed.sum() > 100
    # pinhole rays (what the cloud was before): the wall bends by centimetres at the edges
    pin, _ = merged(())
    assert np.abs(pin[:, 0] - 3.0).max() > 0.05
    assert np.percentile(np.abs(pin[:, 0] - 3.0), 90) > 0.01
    assert _gap_m(a, b, LENS).max() < 0.01 < _gap_m(a, b, ()).max()


def _gap_m(a: tuple[np.ndarray, ...], b: tuple[np.ndarray, ...],
           dist: tuple[float, ...]) -> np.ndarray:
    """Distance across the wall between the two sensors' own clouds where they overlap
    (points of one within 2 cm of the other's along the wall)."""
    from scipy.spatial import cKDTree

    pa, _ = merge_depth_views([DepthView(a[0], a[1], a[2], dist=dist)], voxel_m=0.03)
    pb, _ = merge_depth_views([DepthView(b[0], b[1], b[2], dist=dist)], voxel_m=0.03)
    d, idx = cKDTree(pa[:, 1:]).query(pb[:, 1:], distance_upper_bound=0.02)
    ok = np.isfinite(d)
    assert ok.sum() > 1000  # they do overlap
    return np.abs(pb[ok, 0] - pa[idx[ok], 0])


def test_calibrated_depth_lens_only_for_the_camera_it_was_recorded_with() -> None:
    K = np.array([[365.0, 0.0, 255.5], [0.0, 365.0, 211.5], [0.0, 0.0, 1.0]])
    cams = {"S1": {"depth": {"size": [512, 424], "K": K.tolist(), "dist": list(LENS)},
                   "color": {"size": [1920, 1080], "K": K.tolist(), "dist": [0.1, 0, 0, 0]}},
            "S2": {"depth": {"size": [512, 424], "K": K.tolist(), "dist": []}}}
    assert calibrated_depth_lens(cams, "S1", K, (512, 424)) == LENS
    # the calibration's frames at another size than the node reports: K scales, dist not
    cams_half = {"S1": {"depth": {"size": [256, 212], "K": (K * [[.5], [.5], [1]]).tolist(),
                                  "dist": list(LENS)}}}
    assert calibrated_depth_lens(cams_half, "S1", K, (512, 424)) == LENS
    # pinholes: recorded without a lens, not calibrated, a calibration before lenses
    assert calibrated_depth_lens(cams, "S2", K, (512, 424)) == ()
    assert calibrated_depth_lens(cams, "S3", K, (512, 424)) == ()
    assert calibrated_depth_lens({}, "S1", K, (512, 424)) == ()
    # another camera than the one calibrated (swapped device): not its lens
    K2 = K.copy()
    K2[0, 0] = 380.0
    assert calibrated_depth_lens(cams, "S1", K2, (512, 424)) is None
    assert calibrated_depth_lens({"S1": {"depth": {"dist": [0.1, 0, 0, 0]}}}, "S1", K,
                                 (512, 424)) is None


def test_bad_lens_in_a_view_is_an_input_error() -> None:
    dep, K, T = _wall_view((0.0, 0.0, 1.2), 0.0, ())
    with pytest.raises(InputError, match="4, 5, 8, 12 or 14"):
        merge_depth_views([DepthView(dep, K, T, dist=(0.1, 0.2, 0.3))])


def test_live_cloud_of_simulated_nodes_with_a_depth_lens(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Two simulated nodes render their live depth previews through a depth lens; the
    active calibration recorded that lens; the server's live cloud (``LiveServices``:
    the lens looked up when nodes connect, each frame's view as the cloud loop builds it)
    puts the floor both see flat, within 1 cm, and the pinhole view does not."""
    from app.nodes.backends.sim import SimBackend
    from app.server import calibration as cal
    from app.server.registry import NodeRegistry
    from app.viewer.live import LiveServices
    from engine.calibration.pipeline import CalibrationResult

    monkeypatch.setenv("GAITRIG_TEST_SIM_DEPTH_DIST", ",".join(str(x) for x in LENS))
    nodes = {sid: SimBackend(sid, seed=0) for sid in ("S1", "S2")}
    registry = NodeRegistry()
    infos = {}
    for sid, b in nodes.items():
        infos[sid] = b.open()
        assert b.depth_dist == list(LENS)  # reported in its calibration frames' headers

    async def send(_raw: str) -> None:
        return None

    # the calibration a capture from these nodes saves: poses and each camera model
    poses = {sid: np.asarray(infos[sid].T_world_sensor, float) for sid in nodes}
    cameras = {sid: {"depth": {"size": list(infos[sid].depth_size), "K": infos[sid].depth_K,
                               "dist": list(LENS)}} for sid in nodes}
    res = CalibrationResult(poses, poses, {1: np.eye(4)}, {1: 0.4}, {s: 0.001 for s in nodes},
                            [], [], meta={"cameras": cameras})
    cal.save(tmp_path, res)
    hub = SimpleNamespace(registry=registry, settings=SimpleNamespace(data_dir=tmp_path))
    live = LiveServices(hub, None)  # type: ignore[arg-type]
    for sid in nodes:
        live._on_nodes(registry.connect(sid, "sim", infos[sid], send, True))

    def floor_cloud(use_lens: bool) -> np.ndarray:
        views = []
        for k, (sid, b) in enumerate(nodes.items()):
            img = b.render(4.0, ["depth", "body_index"], 0.5)  # the live preview
            view = live.cloud_view(DepthFrame(sid, k, 4.0, None, img["depth"],
                                              img["body_index"] != 255, 0.5))
            assert view is not None and view.dist == LENS
            # the floor pixels, by OpenCV's rays through the lens (not the cloud's table)
            h, w = view.depth_mm.shape
            T = view.T_world_sensor
            d = _rays(view.K, w, h, LENS) @ T[:3, :3].T
            with np.errstate(divide="ignore", invalid="ignore"):
                z_floor = -T[2, 3] / d[..., 2]
            floor = np.abs(view.depth_mm / 1000.0 - z_floor) < 0.03 * z_floor
            assert floor.sum() > 3000, sid
            depth = np.where(floor, view.depth_mm, 0).astype(np.uint16)
            views.append(DepthView(depth, view.K, T, view.color,
                                   dist=view.dist if use_lens else ()))
        pts, _ = merge_depth_views(views, voxel_m=0.04)
        return pts

    with_lens = floor_cloud(True)
    assert len(with_lens) > 500
    assert np.percentile(np.abs(with_lens[:, 2]), 99) < 0.01
    pinhole = floor_cloud(False)
    assert np.percentile(np.abs(pinhole[:, 2]), 99) > 0.03
