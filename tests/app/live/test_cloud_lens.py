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
    for bad in ([0.1, 0.2, 0.3], [0.1, float("nan"), 0, 0], [0.1] + [0.0] * 11 + [0.01, 0]):
        c = {"S1": {"depth": {**cams["S1"]["depth"], "dist": bad}}}
        assert calibrated_depth_lens(c, "S1", K, (512, 424)) is None, bad


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
            view = live.cloud_view(DepthFrame(sid, k, 4.0, None,
                                              np.asarray(img["depth"], np.uint16),
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


def test_live_lens_source_calibration_when_it_fits_else_the_announced_one(
        tmp_path: Path) -> None:
    """Which depth lens the live cloud uses per node: the active calibration's while the
    node reports the K it was calibrated with, else the lens the node announced
    (``sensor_lens``), else none; an announced lens the ray table cannot model (tilted)
    is not used."""
    from app.nodes.protocol import CameraLens, SensorInfo, SensorLens
    from app.server import calibration as cal
    from app.server.registry import NodeRegistry
    from app.viewer.live import LiveServices
    from engine.calibration.pipeline import CalibrationResult

    K = [[365.0, 0.0, 255.5], [0.0, 365.0, 211.5], [0.0, 0.0, 1.0]]
    K_other = [[380.0, 0.0, 255.5], [0.0, 380.0, 211.5], [0.0, 0.0, 1.0]]
    factory = (-0.1, 0.02, 0.0, 0.0, 0.0)
    tilted = [0.1] + [0.0] * 11 + [0.01, 0.0]

    async def send(_raw: str) -> None:
        return None

    # S1: calibrated with LENS at the K it reports; S2: calibrated, but at another K (a
    # swapped device); S3: not calibrated; S4: not calibrated, a tilted lens; S5: none
    cameras = {sid: {"depth": {"size": [512, 424], "K": Kc, "dist": list(LENS)}}
               for sid, Kc in (("S1", K), ("S2", K_other))}
    poses = {sid: np.eye(4) for sid in ("S1", "S2")}
    cal.save(tmp_path, CalibrationResult(poses, poses, {1: np.eye(4)}, {1: 0.4},
                                         {s: 0.001 for s in poses}, [], [],
                                         meta={"cameras": cameras}))
    registry = NodeRegistry()
    hub = SimpleNamespace(registry=registry, settings=SimpleNamespace(data_dir=tmp_path))
    live = LiveServices(hub, None)  # type: ignore[arg-type]
    sensor = SensorInfo(depth_K=K, depth_size=(512, 424), T_world_sensor=np.eye(4).tolist())
    for sid, dist in (("S1", factory), ("S2", factory), ("S3", factory), ("S4", tilted),
                      ("S5", None)):
        s = registry.connect(sid, "k4a", sensor, send, True)
        live._on_nodes(s)
        # before its announcement: the calibration's lens where it fits, else none
        assert live._depth_lens.get(sid) == (LENS if sid == "S1" else None)
        if dist is not None:
            s.lens = SensorLens(source="factory calibration",
                                depth=CameraLens(size=(512, 424), K=K, dist=list(dist)))
            live._on_nodes(s)  # as the hub calls the listeners on an announcement
    assert live._depth_lens == {"S1": LENS, "S2": factory, "S3": factory}
    # a reconnection (an older agent, announcing nothing) forgets the announced lens
    live._on_nodes(registry.connect("S3", "k4a", sensor, send, True))
    assert "S3" not in live._depth_lens and live._depth_lens["S1"] == LENS


def test_server_live_cloud_of_lens_node_processes_is_flat(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """End to end: a server with the 3D view on (the active calibration recorded the
    nodes' depth lens), two simulated node processes on loopback rendering their depth
    through that lens, a 3D-view client connected through the login proxy: the clouds the
    server draws put the floor both sensors see flat (|z| median 0.3 mm, 99th percentile
    1.9 mm; with the calibration's lens left out, as before nodes announced theirs: 13 mm
    and 57 mm). Without a calibration the nodes' announced lens does it
    (``tests/integration/test_node_lens.py``)."""
    from app.server import calibration as cal
    from engine.calibration.pipeline import CalibrationResult
    from engine.sim.rig import default_avenue_rig

    rig = default_avenue_rig(0)
    poses = {s: rig.sensor(s).T_world_sensor for s in LENS_NODES}
    m = rig.sensor("S1").model
    cameras = {s: {"depth": {"size": [m.depth_width, m.depth_height],
                             "K": m.depth_intrinsics().tolist(), "dist": list(LENS)}}
               for s in LENS_NODES}
    cal.save(tmp_path, CalibrationResult(poses, poses, {1: np.eye(4)}, {1: 0.4},
                                         {s: 0.001 for s in LENS_NODES}, [], [],
                                         meta={"cameras": cameras}))
    z, lens_of, _ = live_floor_of_lens_nodes(tmp_path, monkeypatch)
    assert lens_of == dict.fromkeys(LENS_NODES, LENS)
    assert np.median(z) < 0.003 and np.percentile(z, 99) < 0.01, np.percentile(z, [50, 95, 99])


#: the simulated nodes of :func:`live_floor_of_lens_nodes`
LENS_NODES = ("S1", "S2")


def live_floor_of_lens_nodes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                             env: dict[str, str] | None = None
                             ) -> tuple[np.ndarray, dict[str, tuple[float, ...]],
                                        list[dict[str, object]]]:
    """Run a server with the 3D view on (data in ``tmp_path``: a calibration saved there
    is the active one) and the simulated node processes :data:`LENS_NODES`, rendering their
    depth through :data:`LENS` (``env`` adds to their environment), with a 3D-view client
    connected through the login proxy, until the server drew each node's cloud.

    Returns:
        ``|z|`` (m) of the floor points the server drew (each node's own voxels, away from
        the walls; of frames with their body mask), the depth lens each node's cloud was
        drawn with, and ``GET /api/nodes`` while the nodes were connected.
    """
    import os
    import socket
    import subprocess
    import sys
    import threading
    import time

    import httpx
    import uvicorn
    import viser
    import websockets.sync.client

    from app.config import Settings
    from app.main import create_app
    from app.viewer import live as live_mod
    from app.viewer.scene import sensor_color
    from engine.sim.rig import default_avenue_rig
    from tests.app.test_viewer import _camera_message

    rig = default_avenue_rig(0)
    ids = LENS_NODES
    drawn: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    draw, merge = live_mod.populate_cloud, live_mod.merge_depth_views
    # node colour → its last view: had a body mask, its depth lens
    masked: dict[tuple[int, ...], tuple[bool, tuple[float, ...]]] = {}
    lens_of: dict[str, tuple[float, ...]] = {}

    def merge_spy(views: list[DepthView], *args: object) -> object:
        masked[tuple(views[0].color)] = (views[0].highlight is not None, views[0].dist)
        return merge(views, *args)  # type: ignore[arg-type]

    def spy(server: object, node_id: str, pts: np.ndarray, cols: np.ndarray,
            visible: bool = True) -> object:
        # a depth frame whose body index came too late (streaming.PAIR_WAIT_S, a loaded
        # machine) draws the walker in the sensor's colour: not the floor's to measure
        has_mask, dist = masked.get(tuple(sensor_color(node_id)), (False, ()))
        if has_mask:
            drawn[node_id] = (pts.copy(), cols.copy())
            lens_of[node_id] = dist
        return draw(server, node_id, pts, cols, visible)  # type: ignore[arg-type]

    monkeypatch.setattr(live_mod, "merge_depth_views", merge_spy)
    monkeypatch.setattr(live_mod, "populate_cloud", spy)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = int(s.getsockname()[1])
    settings = Settings(data_dir=tmp_path, viewer_enabled=True, viewer_port=0,
                        node_token="tok-tok-tok", admin_password="pw")
    server = uvicorn.Server(uvicorn.Config(create_app(settings), host="127.0.0.1", port=port,
                                           log_level="warning", ws_per_message_deflate=False))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    env = {**os.environ, "GAITRIG_NODE_TOKEN": "tok-tok-tok", "PYTHONUNBUFFERED": "1",
           "GAITRIG_NODE_MIN_FREE_GB": "0", "GAITRIG_NODE_MIN_FREE_PERCENT": "0",
           "GAITRIG_TEST_SIM_DEPTH_DIST": ",".join(str(x) for x in LENS), **(env or {})}
    procs: list[subprocess.Popen[bytes]] = []
    stop = threading.Event()
    nodes: list[dict[str, object]] = []
    try:
        deadline = time.monotonic() + 30
        while not server.started and time.monotonic() < deadline:
            time.sleep(0.05)
        assert server.started, "the server did not start"
        token = httpx.post(f"http://127.0.0.1:{port}/api/auth/login",
                           json={"username": "admin", "password": "pw"}, timeout=10).json()["token"]
        for sid in ids:
            log = open(tmp_path / f"{sid}.log", "wb")  # noqa: SIM115 - closed with the process
            procs.append(subprocess.Popen(
                [sys.executable, "-m", "app.cli", "node", "--id", sid, "--server",
                 f"ws://127.0.0.1:{port}", "--data-dir", str(tmp_path / "nodes" / sid)],
                env=env, stdout=log, stderr=subprocess.STDOUT))
            log.close()

        def client() -> None:  # the page's 3D view: the server builds clouds while it is open
            with websockets.sync.client.connect(
                    f"ws://127.0.0.1:{port}/viewer",
                    subprotocols=[f"viser-v{viser.__version__}"],  # type: ignore[list-item]
                    additional_headers={"Authorization": f"Bearer {token}"}, max_size=None,
                    compression=None) as ws:
                ws.send(_camera_message())
                while not stop.is_set():
                    try:
                        ws.recv(timeout=0.5)
                    except TimeoutError:
                        continue

        reader = threading.Thread(target=client, daemon=True)
        reader.start()
        deadline = time.monotonic() + 120
        while set(drawn) != set(ids) and time.monotonic() < deadline:
            assert all(p.poll() is None for p in procs), [
                (tmp_path / f"{s}.log").read_text(errors="replace")[-2000:] for s in ids]
            time.sleep(0.2)
        assert set(drawn) == set(ids), f"clouds drawn: {sorted(drawn)}"
        nodes = httpx.get(f"http://127.0.0.1:{port}/api/nodes", timeout=10,
                          headers={"Authorization": f"Bearer {token}"}).json()
    finally:
        stop.set()
        for p in procs:
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=15)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        server.should_exit = True
        thread.join(15)
    lo, hi = rig.room.floor_min + 0.3, rig.room.floor_max - 0.3  # away from the walls
    floor = []
    for sid, (pts, cols) in drawn.items():
        own = (cols == sensor_color(sid)).all(axis=1)  # not the walker's, nor mixed voxels
        inner = ((pts[:, :2] > lo) & (pts[:, :2] < hi)).all(axis=1) & (np.abs(pts[:, 2]) < 0.2)
        assert (own & inner).sum() > 300, sid
        floor.append(pts[own & inner, 2])
    return np.abs(np.concatenate(floor)), lens_of, nodes
