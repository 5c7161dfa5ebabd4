"""Live view building blocks against known answers: cloud, panels, flow control, planning."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import numpy as np
import open3d as o3d
import pytest

from app.server.registry import LatestImage
from app.server.streaming import HIGHLIGHT_RGB, Panel, Watcher, colourise, decode_pair
from app.viewer.cloud import DepthView, merge_depth_views, scale_intrinsics, serialise_cloud
from app.viewer.live import fuse_skeletons
from app.viewer.planning import Planner
from engine.coverage import sensor_pose, sensors_from_rig
from engine.errors import InputError
from engine.sim.rig import default_avenue_rig, load_rig


def _floor_view(h: float = 1.2, pitch: float = -40.0) -> tuple[DepthView, np.ndarray]:
    """Depth image of the floor (z = 0) seen by a camera at height h, by ray casting."""
    W, H = 160, 120
    K = np.array([[120.0, 0, 79.5], [0, 120.0, 59.5], [0, 0, 1]])
    T = sensor_pose((0.5, -0.3, h), 20.0, pitch)
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u, float)], -1)
    dz = rays @ T[:3, :3].T[:, 2]  # world z change per unit camera z
    with np.errstate(divide="ignore"):
        z = np.where(dz < -1e-6, -T[2, 3] / dz, 0.0)
    depth = np.where((z > 0.3) & (z < 8.0), np.round(z * 1000), 0).astype(np.uint16)
    return DepthView(depth, K, T, (10, 200, 30)), T


def test_merged_cloud_lies_on_the_floor_and_matches_open3d() -> None:
    view, T = _floor_view()
    pts, cols = merge_depth_views([view], voxel_m=0.05)
    assert len(pts) > 200 and pts.dtype == np.float32
    assert np.abs(pts[:, 2]).max() < 0.01  # depth rounding to 1 mm, voxel means
    assert (cols == (10, 200, 30)).all()
    h, w = view.depth_mm.shape
    intr = o3d.camera.PinholeCameraIntrinsic(w, h, 120.0, 120.0, 79.5, 59.5)
    pcd = o3d.geometry.PointCloud.create_from_depth_image(
        o3d.geometry.Image(view.depth_mm), intr, depth_scale=1000.0, depth_trunc=8.0)
    pcd.transform(T)
    ref = pcd.voxel_down_sample(0.05)
    assert abs(len(ref.points) - len(pts)) <= 0.02 * len(pts)
    blob = serialise_cloud(pts, cols)
    assert len(blob) == 4 + 15 * len(pts)


def test_highlight_mask_and_scaled_intrinsics() -> None:
    view, _ = _floor_view()
    mask = np.zeros(view.depth_mm.shape, bool)
    mask[80:, :] = True
    _pts, cols = merge_depth_views([DepthView(view.depth_mm, view.K, view.T_world_sensor,
                                             (0, 0, 255), mask)], voxel_m=0.05)
    assert (cols == HIGHLIGHT_RGB).all(axis=1).any() and (cols == (0, 0, 255)).all(axis=1).any()
    K2 = scale_intrinsics(view.K, 0.5)
    assert K2[0, 0] == 60.0 and K2[0, 2] == pytest.approx(39.75)
    with pytest.raises(InputError):
        merge_depth_views([view], voxel_m=0.0)


def test_flying_pixels_behind_a_body_are_not_drawn() -> None:
    """A body in front of the floor with a time-of-flight edge: pixels beside it read a
    depth between the body and the floor. The live cloud drops them (they floated over
    the floor); the body and the floor stay whole."""
    view, T = _floor_view()
    depth = view.depth_mm.astype(np.int64)
    body = np.zeros(depth.shape, bool)
    body[0:100, 60:80] = True
    depth[body] = 1200  # 1.2 m from the camera, in front of the floor (1.6–4.6 m)
    rows = np.arange(0, 100)
    behind = depth[rows, 80] > 1900
    depth[rows, 80] = np.where(behind, (1200 + depth[rows, 80]) // 2, depth[rows, 80])  # mixed
    view = DepthView(depth.astype(np.uint16), view.K, T, (10, 200, 30), body)

    def over_the_floor(p: np.ndarray, c: np.ndarray) -> int:
        own = (c == (10, 200, 30)).all(axis=1)
        return int((own & (p[:, 2] > 0.03)).sum())

    kept = merge_depth_views([view], voxel_m=0.02, jump_edge_deg=None)
    assert behind.sum() > 20 and over_the_floor(*kept) >= 20  # floating points, before
    pts, cols = merge_depth_views([view], voxel_m=0.02)
    assert over_the_floor(pts, cols) == 0
    hl = (cols == HIGHLIGHT_RGB).all(axis=1)
    assert hl.sum() == (kept[1] == HIGHLIGHT_RGB).all(axis=1).sum()  # the body whole
    assert (~hl).sum() >= 0.95 * (~(kept[1] == HIGHLIGHT_RGB).all(axis=1)).sum()


def test_panel_colours_and_decode() -> None:
    import cv2

    depth = np.full((20, 30), 2000, np.uint16)
    depth[:, :5] = 0
    body = np.full((20, 30), 255, np.uint8)
    body[5:10, 10:20] = 0
    img = colourise(depth, body != 255)
    assert (img[:, :5] == 0).all()  # no measurement → black
    b, g, r = img[7, 15].astype(int)
    assert r > 150 and g < 20 and b > 110  # body in the highlight colour
    d = LatestImage(1.0, 2.0, "png", cv2.imencode(".png", depth)[1].tobytes(), {"scale": 0.5})
    bi = LatestImage(1.0, 2.0, "png", cv2.imencode(".png", body)[1].tobytes(), {})
    f = decode_pair("S1", 3, d, bi)
    assert f.t_capture == 2.0 and f.scale == 0.5 and f.body is not None and f.body.sum() == 50
    with pytest.raises(ValueError):
        decode_pair("S1", 3, bi, None)  # an 8-bit image is no depth


def test_watcher_drops_instead_of_queueing() -> None:
    async def run() -> Watcher:
        sent: list[bytes] = []

        async def send(b: bytes) -> None:
            sent.append(b)

        w = Watcher(send=send, window=2)
        task = asyncio.create_task(w.run())
        for k in range(50):
            w.offer(Panel("S1", k, b"1" + bytes([k]), None))
            w.offer(Panel("S2", k, b"2" + bytes([k]), None))
            await asyncio.sleep(0)
        await asyncio.sleep(0.01)
        # two panels per node, then nothing more until the page acks
        assert w.in_flight == 4 and len(sent) == 4
        assert len(w.pending) <= 2  # at most the newest panel per node waits
        w.ack(1, "S2")  # S2's credit frees S2's newest panel only
        await asyncio.sleep(0.01)
        assert len(sent) == 5 and sent[-1] == b"2" + bytes([49]) and "S1" in w.pending
        w.ack(2)  # acks without a node free the oldest in flight: S1's
        await asyncio.sleep(0.01)
        assert sent[-1] == b"1" + bytes([49]) and not w.pending
        w.ack(99)
        assert w.in_flight == 0
        task.cancel()
        return w

    w = asyncio.run(run())
    assert w.dropped > 90


def test_fused_skeleton_is_the_tracked_mean_and_ignores_another_person() -> None:
    J = 25
    a = np.zeros((1, J, 3))
    a[0, :, 2] = np.linspace(0, 1.7, J)
    b = a + 0.02
    other = a + np.array([3.0, 0, 0])
    st = np.full((1, J), 2, np.uint8)
    fused = fuse_skeletons({"S1": (a, st), "S2": (b, st), "S3": (other, st)})
    assert fused is not None
    assert np.allclose(fused, a[0] + 0.01)
    assert fuse_skeletons({}) is None


def test_planner_move_save_and_reload(tmp_path) -> None:  # type: ignore[no-untyped-def]
    rig = default_avenue_rig(None)
    p = Planner(sensors_from_rig(rig), rig)
    before = p.summary()
    p.move("S1", yaw_deg=35.0)
    after = p.summary()
    assert after["version"] == before["version"] + 1
    assert after["walkway_covered_fraction"] < before["walkway_covered_fraction"]
    s1 = next(s for s in after["sensors"] if s["id"] == "S1")
    assert s1["moved"] and s1["yaw_deg"] == pytest.approx(35.0, abs=1e-6)
    path = p.save(tmp_path, "plan_1")
    again = load_rig(path)
    assert np.allclose(again.sensor("S1").T_world_sensor, p.sensors[0].T_world_sensor)
    assert len(again.markers) == len(rig.markers)
    with pytest.raises(InputError):
        p.save(tmp_path, "../x")
    with pytest.raises(InputError):
        p.move("S9", yaw_deg=0.0)
    with pytest.raises(InputError):
        p.move("S1", position=(0.0, 0.0, 9.0))
    rows = p.placement_rows()
    assert rows[1]["id"] == "S2" and rows[1]["distance_cm"] == pytest.approx(260.0, abs=0.1)
    assert p.png()[:4] == b"\x89PNG"
    p.reset()
    assert not any(s["moved"] for s in p.summary()["sensors"])


def test_dragging_a_handle_moves_the_plan_and_redraws_the_3d_map(tmp_path) -> None:  # type: ignore[no-untyped-def]
    import viser

    from app.config import Settings
    from app.nodes.protocol import SensorInfo
    from app.server.hub import Hub
    from app.viewer.live import LiveServices
    from engine.geometry import quat_from_matrix

    async def send(_t: str) -> None:
        return None

    hub = Hub(Settings(data_dir=tmp_path))
    rig = default_avenue_rig(None)
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        live = LiveServices(hub, server)
        for s in rig.sensors:
            hub.registry.connect(s.id, "sim", SensorInfo(T_world_sensor=s.T_world_sensor.tolist()),
                                 send, True)
        planner = live.get_planner()
        assert sorted(live._handles) == [s.id for s in rig.sensors]
        v0, walk0 = planner.version, planner.summary()["walkway_covered_fraction"]
        T = sensor_pose((2.4, 1.0, 1.0), 35.0, -8.0)  # S1 turned away from the walkway
        live.apply_drag("S1", quat_from_matrix(T[:3, :3]), T[:3, 3])
        assert planner.version == v0 + 1
        assert planner.summary()["walkway_covered_fraction"] < walk0
        assert len(live.coverage_draw_ms) >= 2  # initial map + the redraw after the drag
        live.apply_drag("S1", (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 9.0))  # refused: too high
        assert planner.version == v0 + 1
    finally:
        server.stop()


def test_planner_says_where_its_poses_come_from(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Before a calibration the plan starts from the simulated rig's true poses; once one
    is active, from that calibration (and it says which sensors it does not cover)."""
    from app.config import Settings
    from app.nodes.protocol import SensorInfo
    from app.server.calibration import apply_to_registry, calibration_dir
    from app.server.hub import Hub
    from app.viewer.live import LiveServices
    from engine.calibration.store import save_version
    from tests.app.calibration.sim_truth import truth_calibration

    async def send(_t: str) -> None:
        return None

    hub = Hub(Settings(data_dir=tmp_path))
    rig = default_avenue_rig(0)
    live = LiveServices(hub, None)
    for s in rig.sensors:
        hub.registry.connect(s.id, "sim", SensorInfo(T_world_sensor=s.T_world_sensor.tolist()),
                             send, True)
    assert live.get_planner().source == "true poses of the simulated rig (not calibrated)"
    calibrated = ["S1", "S2", "S3", "S4"]
    save_version(truth_calibration(calibrated), calibration_dir(tmp_path))
    apply_to_registry(hub.registry, tmp_path)
    src = live.get_planner().source
    assert src.startswith("calibration 1 (S1, S2, S3, S4); S5, S6 as reported"), src


def test_api_subscription_cannot_break_the_live_stream(monkeypatch: pytest.MonkeyPatch) -> None:
    """One subscription per node: the live view's stays in force, the API's is added to it."""
    from types import SimpleNamespace

    from app.nodes.protocol import Subscribe
    from app.server import streaming
    from app.server.streaming import LiveStreams

    monkeypatch.setattr(streaming, "IDLE_UNSUBSCRIBE_S", 0.05)
    told: list[Subscribe] = []

    async def send(raw: str) -> None:
        told.append(Subscribe.model_validate_json(raw))

    node = SimpleNamespace(id="S1", connected=True, connected_at=1.0, send=send, images={})
    hub = SimpleNamespace(registry=SimpleNamespace(nodes={"S1": node}))

    async def until(pred: Callable[[], bool]) -> None:
        for _ in range(1000):  # the pump looks every 0.5 s; a loaded machine may be slow
            if pred():
                return
            await asyncio.sleep(0.02)
        raise AssertionError("the nodes were not told in 20 s")

    async def run() -> None:
        live = LiveStreams(hub, fps=15.0, scale=0.5)  # type: ignore[arg-type]
        colour = Subscribe(streams=["color"], fps=2.0, scale=1.0, format="jpeg")
        # nobody watches: the API's subscription goes to the node as asked
        assert await live.request("S1", colour) == colour and told[-1] == colour
        # the Live page opens: the node streams the live view's images plus the colour
        w = Watcher(send=lambda b: asyncio.sleep(0))
        live.add_watcher(w)
        await until(lambda: told[-1] != colour)
        assert told[-1].streams == ["depth", "body_index", "color"]
        assert (told[-1].format, told[-1].scale, told[-1].fps) == ("png", 0.5, 15.0)
        # another request, even a stop or a different form, cannot change the live part
        n = len(told)
        got = await live.request("S1", Subscribe(streams=["depth"], fps=0))
        assert got == live.live_subscription() and told[-1] == got and len(told) == n + 1
        got = await live.request("S1", Subscribe(streams=["depth"], fps=30, scale=1.0,
                                                 format="jpeg"))
        assert got is not None and (got.format, got.scale, got.fps) == ("png", 0.5, 30.0)
        assert set(got.streams) == {"depth", "body_index"}
        # the node reconnects: told again; unchanged state is not re-sent
        n = len(told)
        await asyncio.sleep(0.7)
        assert len(told) == n
        node.connected_at = 2.0
        await until(lambda: len(told) > n)
        assert len(told) == n + 1 and told[-1] == got
        # the page closes: after the idle time the API's own request applies again
        live.remove_watcher(w)
        await until(lambda: told[-1].format == "jpeg")
        assert told[-1] == Subscribe(streams=["depth"], fps=30, scale=1.0, format="jpeg")
        await live.request("S1", Subscribe(streams=[], fps=0))
        assert told[-1].fps == 0 and live.effective("S1") is None
        await live.stop()

    asyncio.run(run())


def test_sim_preview_is_the_downscaled_frame_and_recordings_stay_full_size() -> None:
    """The live panels' half-size depth is rendered directly, with the geometry of a
    nearest-neighbour downscale of the full frame (what the 3D view's intrinsics assume)."""
    import cv2

    from app.nodes.backends.sim import SimBackend

    sim = SimBackend("S1", images=True)
    sim.open()
    frame = next(iter(sim.frames()))
    sim.close()
    assert frame.preview is not None
    small = frame.preview(["depth", "body_index"], 0.5)
    full = frame.images(["depth", "body_index"])  # what a recording stores
    assert full["depth"].shape == (424, 512) and small["depth"].shape == (212, 256)
    assert small["depth"].dtype == np.uint16 and small["body_index"].dtype == np.uint8
    # the walker in view of S1 (a standing start by the first pair of sensors)
    t = 4.0
    small = sim.render(t, ["depth", "body_index"], 0.5)
    ref = {k: cv2.resize(v, (256, 212), interpolation=cv2.INTER_NEAREST)
           for k, v in sim.render(t, ["depth", "body_index"]).items()}
    both = (small["depth"] > 0) & (ref["depth"] > 0)
    assert np.mean((small["depth"] > 0) == (ref["depth"] > 0)) > 0.97
    assert np.median(np.abs(small["depth"][both].astype(int) - ref["depth"][both])) < 15
    body_s, body_r = small["body_index"] != 255, ref["body_index"] != 255
    assert body_r.sum() > 200, "the walker should be in view of S1 at t = 4 s"
    assert (body_s & body_r).sum() > 0.9 * body_r.sum()
    # colour cannot be previewed: rendered full size, then downscaled like the agent would
    c = sim.render(t, ["color", "depth"], 0.5)
    assert c["color"].shape == (180, 320, 3) and c["depth"].shape == (212, 256)
    # the frame loop poses the walker for a whole chunk at once: the same body
    from app.nodes.backends.sim import world_time
    from engine.sim.walker import capsules_mesh

    hosts, _series, _t0, caps = sim._chunk(1_000_000.0)
    k = len(hosts) // 2
    V, F, _ = capsules_mesh(caps[0][k], caps[1][k], caps[2])
    V2, F2, _ = sim._walker.body_mesh(world_time(float(hosts[k])))
    assert np.allclose(V, V2, atol=1e-9) and (F == F2).all()


def test_clouds_far_from_the_origin_keep_millimetres() -> None:
    """viser sends point clouds as float16 by default; ours go as float32."""
    import viser

    from app.viewer.live import populate_cloud

    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        pts = (np.array([[1000.0, -250.0, 0.0]]) + np.random.default_rng(0).random((500, 3))
               ).astype(np.float32)
        h = populate_cloud(server, "S1", pts, np.zeros((500, 3), np.uint8))
        assert h.points.dtype == np.float32
        assert np.abs(h.points - pts).max() < 1e-3
        # float16 would have moved them by up to a quarter metre
        assert np.abs(pts.astype(np.float16).astype(np.float32) - pts).max() > 0.1
        assert populate_cloud(server, "S1", pts[:0], np.zeros((0, 3), np.uint8)) is None
    finally:
        server.stop()


def test_point_cloud_toggles_are_listed_in_sensor_order(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The 3D view's "Point cloud per sensor" listed the sensors in the order their first
    clouds arrived (S1, S2, S4, S6, S5, S3 in the demo); it lists them S1 … S10."""
    import viser

    from app.config import Settings
    from app.server.hub import Hub
    from app.viewer.live import LiveServices

    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        live = LiveServices(Hub(Settings(data_dir=tmp_path)), server)
        for nid in ("S2", "S10", "S6", "S1", "K4A-b", "K4A-a"):
            live._node_toggle(nid)
        listed = sorted(live._node_toggles, key=lambda n: live._node_toggles[n].order)
        assert listed == ["K4A-a", "K4A-b", "S1", "S2", "S6", "S10"]
    finally:
        server.stop()


def test_pump_idles_until_watched(monkeypatch: pytest.MonkeyPatch) -> None:
    """Nobody watching and nothing subscribed: the pump looks for images only at its
    subscription checks, not every 10 ms; with a watcher it polls again."""
    from types import SimpleNamespace

    from app.server.streaming import POLL_S, SUB_CHECK_S, LiveStreams

    async def send(raw: str) -> None:
        pass

    node = SimpleNamespace(id="S1", connected=True, connected_at=1.0, send=send, images={})
    hub = SimpleNamespace(registry=SimpleNamespace(nodes={"S1": node}))

    async def run() -> None:
        live = LiveStreams(hub)  # type: ignore[arg-type]
        looks: list[float] = []
        monkeypatch.setattr(live, "_check", lambda s, now: looks.append(now))
        live.start()
        await asyncio.sleep(2.2 * SUB_CHECK_S)
        # a check at start and one per SUB_CHECK_S (a 10 ms poll: > 100)
        assert 1 <= len(looks) <= 4, len(looks)
        n = len(looks)
        live.add_watcher(Watcher(send=lambda b: asyncio.sleep(0)))
        for _ in range(300):  # polling again while somebody watches (a loaded machine: slow)
            await asyncio.sleep(POLL_S)
            if len(looks) - n >= 10:
                break
        assert len(looks) - n >= 10
        await live.stop()

    asyncio.run(run())
