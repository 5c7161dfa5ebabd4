"""The viser 3D view: floor, sensor frustums, and its life in the FastAPI lifespan."""

from __future__ import annotations

import json
import socket
from collections.abc import Iterator
from pathlib import Path

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
