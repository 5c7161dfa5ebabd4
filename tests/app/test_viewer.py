"""The viser 3D view: floor, sensor frustums, and its life in the FastAPI lifespan."""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import viser
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from app.nodes.protocol import Hello, SensorInfo, dump
from app.viewer.scene import SensorView, populate_floor, populate_sensors, populate_skeleton
from engine.geometry import look_at, quat_to_matrix


def _names(server: viser.ViserServer) -> set[str]:
    # viser keeps its scene handles by node name (private, but the only read-back there is)
    return set(server.scene._handle_from_node_name)


@pytest.fixture
def server() -> Iterator[viser.ViserServer]:
    s = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    yield s
    s.stop()


def test_floor_and_sensors(server: viser.ViserServer) -> None:
    populate_floor(server)
    T1 = look_at([0.0, 1.0, 1.2], [3.0, 0.0, 0.9])
    T2 = look_at([2.5, -1.0, 1.2], [5.0, 0.0, 0.9])
    populate_sensors(server, [SensorView("S1", T1), SensorView("S2", T2, connected=False)])
    names = _names(server)
    assert {"/floor/grid", "/floor/origin", "/sensors/S1", "/sensors/S1/frustum",
            "/sensors/S1/label", "/sensors/S2/frustum"} <= names
    h = server.scene._handle_from_node_name["/sensors/S1"]
    np.testing.assert_allclose(h.position, T1[:3, 3], atol=1e-6)
    np.testing.assert_allclose(quat_to_matrix(h.wxyz), T1[:3, :3], atol=1e-6)
    label = server.scene._handle_from_node_name["/sensors/S2/label"]
    assert "offline" in label.text  # type: ignore[attr-defined]
    populate_sensors(server, [SensorView("S2", T2)])  # redraw replaces the panel
    names = _names(server)
    assert "/sensors/S1" not in names and "/sensors/S2" in names


def test_skeleton_panel(server: viser.ViserServer) -> None:
    from engine.skeleton import KINECT_V2, TrackingState

    populate_sensors(server, [SensorView("S1", np.eye(4))])
    J = len(KINECT_V2.joints)
    pos = np.random.default_rng(0).normal(size=(1, J, 3)).astype(np.float32)
    st = np.full((1, J), TrackingState.TRACKED, np.uint8)
    st[0, KINECT_V2.index("AnkleLeft")] = TrackingState.INFERRED
    pos[0, KINECT_V2.index("Head")] = np.nan
    populate_skeleton(server, "S1", pos, st)
    h = server.scene._handle_from_node_name["/sensors/S1/skeleton"]
    segs = np.asarray(h.points)  # type: ignore[attr-defined]
    # 24 bones; the head's one is missing (no estimate)
    assert segs.shape == (23, 2, 3)
    ankle = pos[0, KINECT_V2.index("AnkleLeft")]
    cols = np.asarray(h.colors)  # type: ignore[attr-defined]
    grey = [np.allclose(s[1], ankle) or np.allclose(s[0], ankle) for s in segs]
    assert sum(grey) == 2 and all((cols[i] == 150).all() for i, g in enumerate(grey) if g)
    populate_skeleton(server, "S1", pos[:0], st[:0])  # body gone
    assert "/sensors/S1/skeleton" not in _names(server)


def _port_open(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


def test_viewer_lives_in_the_lifespan(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path, viewer_enabled=True, viewer_port=0,
                        node_token="tok-tok-tok", admin_password="pw")
    T = look_at([0.0, 1.0, 1.2], [3.0, 0.0, 0.9])
    with TestClient(create_app(settings)) as client:
        viewer = client.app.state.viewer  # type: ignore[attr-defined]
        assert viewer is not None and _port_open(viewer.port)
        with client.websocket_connect("/ws/node") as ws:
            info = SensorInfo(T_world_sensor=T.tolist())
            ws.send_text(dump(Hello(node_id="S1", token="tok-tok-tok", sensor=info)))
            assert json.loads(ws.receive_text())["type"] == "welcome"
            assert "/sensors/S1/frustum" in _names(viewer.server)
        port = viewer.port
        tok = client.post("/api/auth/login", json={"username": "admin", "password": "pw"})
        sysinfo = client.get("/api/system", headers={"Authorization": "Bearer "
                                                     + tok.json()["token"]}).json()
        assert sysinfo["viewer_url"] == "/viewer/"  # behind the login, same port
    assert not _port_open(port)


def test_viewer_is_behind_the_login(tmp_path: Path) -> None:
    """The 3D view (live skeletons and depth of a subject) is served on the console's port
    to a logged-in session only: the page and its websocket are refused without one."""
    from starlette.websockets import WebSocketDisconnect

    settings = Settings(data_dir=tmp_path, viewer_enabled=True, viewer_port=0,
                        node_token="tok-tok-tok", admin_password="pw")
    with TestClient(create_app(settings)) as client:
        r = client.get("/viewer/")
        assert r.status_code == 401 and "not logged in" in r.json()["detail"]
        with pytest.raises(WebSocketDisconnect) as refused, \
                client.websocket_connect("/viewer") as ws:
            ws.receive_bytes()
        assert refused.value.code == 4401
        assert client.get("/viewer/../api/system").status_code in (401, 404)

        client.post("/api/auth/login", json={"username": "admin", "password": "pw"})
        page = client.get("/viewer/")  # the session cookie, as the console's iframe sends it
        assert page.status_code == 200 and "text/html" in page.headers["content-type"]
        assert "viser" in page.text.lower()
        # the viser client's own subprotocol, passed through to the viser server
        with client.websocket_connect("/viewer", subprotocols=[f"viser-v{viser.__version__}"]
                                      ) as ws:
            first = ws.receive_bytes()  # viser's opening messages, forwarded
            assert len(first) > 0


def test_viewer_proxy_says_when_the_view_is_off(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path, viewer_enabled=False, node_token="tok-tok-tok",
                        admin_password="pw")
    with TestClient(create_app(settings)) as client:
        client.post("/api/auth/login", json={"username": "admin", "password": "pw"})
        r = client.get("/viewer/")
        assert r.status_code == 404 and "--no-viewer" in r.json()["detail"]
        assert client.get("/api/system").json()["viewer_url"] is None


# ------------------------------------------------------- the proxy with a real server


def _wait_for(cond: Callable[[], bool], timeout_s: float, what: str,
              tick: Callable[[], None] = lambda: None) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        tick()
        time.sleep(0.05)


@pytest.fixture
def live_server(tmp_path: Path) -> Iterator[tuple[int, Any, str]]:
    """A real server (uvicorn in a thread: the proxy's backpressure needs real sockets,
    which TestClient does not have) with the 3D view on; its port, viewer and a token."""
    import httpx
    import uvicorn

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = int(s.getsockname()[1])
    settings = Settings(data_dir=tmp_path, viewer_enabled=True, viewer_port=0,
                        node_token="tok-tok-tok", admin_password="pw")
    server = uvicorn.Server(uvicorn.Config(create_app(settings), host="127.0.0.1", port=port,
                                           log_level="warning", ws_per_message_deflate=False))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        _wait_for(lambda: server.started, 30, "the server to start")
        r = httpx.post(f"http://127.0.0.1:{port}/api/auth/login",
                       json={"username": "admin", "password": "pw"}, timeout=10)
        yield port, server.config.app.state.viewer, r.json()["token"]
    finally:
        server.should_exit = True
        thread.join(15)


def _camera_message() -> bytes:
    # what the viser page sends first: viser counts a client from its first camera message
    import msgspec

    return msgspec.msgpack.encode({
        "type": "ViewerCameraMessage", "wxyz": [1.0, 0.0, 0.0, 0.0], "position": [0.0, -3.0, 2.0],
        "fov": 1.0, "near": 0.01, "far": 100.0, "image_height": 720, "image_width": 1280,
        "look_at": [3.0, 0.0, 1.0], "up_direction": [0.0, 0.0, 1.0]})


def test_proxy_drops_a_browser_that_reads_nothing(
        live_server: tuple[int, Any, str], monkeypatch: pytest.MonkeyPatch) -> None:
    """A browser tab that stops reading (frozen, backgrounded) must not make the server
    buffer the 3D view's stream for it without bound: the proxy stops reading from viser
    (which keeps only the newest state per scene node), then drops that browser with close
    code 1013 and lets go of its viser stream."""
    from websockets.client import ClientProtocol
    from websockets.uri import parse_uri

    from app.viewer import proxy

    monkeypatch.setattr(proxy, "SEND_STALL_S", 0.5)
    port, viewer, token = live_server
    proto = ClientProtocol(parse_uri(f"ws://127.0.0.1:{port}/viewer"),
                           subprotocols=[f"viser-v{viser.__version__}"],  # type: ignore[list-item]
                           max_size=None)
    req = proto.connect()
    req.headers["Authorization"] = f"Bearer {token}"
    proto.send_request(req)
    sock = socket.socket()
    # a small receive window: the stall reaches the server after little data
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 16 * 1024)
    sock.settimeout(10.0)
    sock.connect(("127.0.0.1", port))
    try:
        sock.sendall(b"".join(proto.data_to_send()))
        while proto.handshake_exc is None and not any(
                hasattr(e, "status_code") for e in proto.events_received()):
            proto.receive_data(sock.recv(65536))
        assert proto.handshake_exc is None
        proto.send_binary(_camera_message())  # browser → viser goes through the proxy
        sock.sendall(b"".join(proto.data_to_send()))
        _wait_for(lambda: len(viewer.server.get_clients()) == 1, 10, "viser to see the browser")

        # from here on the browser reads nothing; the scene keeps changing (~5 MB clouds
        # under four names, as the live view redraws its per-sensor clouds)
        rng = np.random.default_rng(0)
        pts = rng.normal(size=(350_000, 3)).astype(np.float32)
        cols = rng.integers(0, 255, size=(350_000, 3), dtype=np.uint8)
        k = iter(range(10**6))

        def redraw() -> None:
            viewer.server.scene.add_point_cloud(f"/stall/{next(k) % 4}", pts, cols)

        _wait_for(lambda: len(viewer.server.get_clients()) == 0, 30,
                  "the proxy to let go of the stalled browser's viser stream", redraw)

        # the browser reads again: what was on the wire, then the close frame with its code
        while proto.close_rcvd is None:
            data = sock.recv(1 << 20)
            if not data:
                break
            proto.receive_data(data)
            proto.events_received()
        assert proto.close_rcvd is not None, "the proxy closed without a close frame"
        assert proto.close_rcvd.code == 1013
        assert "stalled" in proto.close_rcvd.reason and "reload" in proto.close_rcvd.reason
    finally:
        sock.close()


def test_proxy_forwards_the_stream_and_lets_go(live_server: tuple[int, Any, str]) -> None:
    """Over real sockets: viser's scene reaches the browser through the proxy, the
    browser's messages reach viser, and a browser that leaves ends its viser stream."""
    import websockets.sync.client
    import zstandard

    port, viewer, token = live_server
    with websockets.sync.client.connect(
            f"ws://127.0.0.1:{port}/viewer", subprotocols=[f"viser-v{viser.__version__}"],  # type: ignore[list-item]
            additional_headers={"Authorization": f"Bearer {token}"}, max_size=None,
            compression=None) as ws:
        assert ws.subprotocol == f"viser-v{viser.__version__}"
        ws.send(_camera_message())
        _wait_for(lambda: len(viewer.server.get_clients()) == 1, 10, "viser to see the browser")
        viewer.server.scene.add_point_cloud("/proxied", np.zeros((1000, 3), np.float32),
                                            (255, 0, 0))
        dctx = zstandard.ZstdDecompressor()
        seen = False
        deadline = time.monotonic() + 10
        while not seen and time.monotonic() < deadline:
            msg = ws.recv(timeout=5)
            assert isinstance(msg, bytes)
            # viser's framing: sizes, then its zstd-compressed msgpack (names in there)
            n_inner, n_comp = (int.from_bytes(msg[i:i + 8], "little") for i in (0, 8))
            seen = b"/proxied" in dctx.decompress(msg[16:16 + n_comp], max_output_size=n_inner)
        assert seen, "the new point cloud never came through the proxy"
    _wait_for(lambda: len(viewer.server.get_clients()) == 0, 10, "the proxy to close viser's side")


def test_fused_skeleton_drawn_only_while_someone_looks(server: viser.ViserServer,
                                                       tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """With no browser on the 3D view the live fused skeleton is not redrawn (it cost the
    idle server CPU at every frame); the first frame after one connects draws it."""
    from app.server.hub import Hub
    from app.server.registry import LatestSkeleton
    from app.viewer.live import LiveServices
    from engine.skeleton import KINECT_V2, TrackingState

    async def send(_text: str) -> None:
        pass

    hub = Hub(Settings(data_dir=tmp_path))
    live = LiveServices(hub, server)
    s = hub.registry.connect("S1", "sim", SensorInfo(T_world_sensor=np.eye(4).tolist()),
                             send, True)
    J = len(KINECT_V2.joints)
    pos = np.random.default_rng(0).normal(size=(1, J, 3)).astype(np.float32)
    s.skeleton = LatestSkeleton(1, 0.0, time.time(), pos,
                                np.full((1, J), TrackingState.TRACKED, np.uint8), [0])
    live._on_skeleton(s)
    assert "/fused/skeleton" not in _names(server)
    monkeypatch.setattr(server, "get_clients", lambda: {1: object()})  # a browser
    live._on_skeleton(s)
    assert "/fused/skeleton" in _names(server)


def test_sensor_skeletons_drawn_only_while_someone_looks(tmp_path: Path) -> None:
    """Skeleton frames reach the 3D view only while a browser shows it (drawing them for
    nobody cost the idle server CPU); the first frame after one connects is drawn."""
    from app.nodes.protocol import encode_skeletons
    from engine.skeleton import KINECT_V2, TrackingState

    settings = Settings(data_dir=tmp_path, viewer_enabled=True, viewer_port=0,
                        node_token="tok-tok-tok", admin_password="pw")
    J = len(KINECT_V2.joints)
    pos = np.random.default_rng(0).normal(size=(1, J, 3)).astype(np.float32)
    st = np.full((1, J), TrackingState.TRACKED, np.uint8)
    with TestClient(create_app(settings)) as client:
        viewer = client.app.state.viewer  # type: ignore[attr-defined]
        with client.websocket_connect("/ws/node") as ws:
            ws.send_text(dump(Hello(node_id="S1", token="tok-tok-tok",
                                    sensor=SensorInfo(T_world_sensor=np.eye(4).tolist()))))
            assert json.loads(ws.receive_text())["type"] == "welcome"

            def skeleton_then_round_trip(seq: int) -> None:
                ws.send_bytes(encode_skeletons(seq, 10.0 + seq, pos, st, [0]))
                ws.send_text("not json")  # answered once the skeleton was handled
                while json.loads(ws.receive_text())["type"] != "error":
                    pass

            skeleton_then_round_trip(1)
            assert "/sensors/S1/skeleton" not in _names(viewer.server)
            viewer.server.get_clients = lambda: {1: object()}  # a browser
            skeleton_then_round_trip(2)
            assert "/sensors/S1/skeleton" in _names(viewer.server)
