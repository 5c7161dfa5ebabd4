"""KSCC API: trapezoid numbers, live calibration progress over scripted nodes, the
comparison in the universal frame, mismatched joint sets, and a two-site link between two
real servers on loopback (wrong token refused, right token streams)."""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import uvicorn
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from app.nodes.protocol import Hello, Pong, SensorInfo, dump, encode_skeletons
from engine.coverage import sensor_pose
from engine.skeleton import KINECT_V1, KINECT_V2, JointSet

NODE_TOKEN = "kscc-node-token-1"
PW = "kscc-admin-pw"
LINK_TOKEN = "site-b-link-token-2026"


def standing_person(at: tuple[float, float], facing_deg: float) -> np.ndarray:
    """World joints (25, 3) of the simulated walker standing still, placed and turned."""
    from engine.sim.walker import Walker, WalkerParams

    w = Walker(WalkerParams(), [0.0, 0.0, 0.0], [6.0, 0.0, 0.0], start_time=100.0, seed=1)
    J = w.joints(np.array([100.0]))[0]  # standing at its start, before walking
    J[:, :2] -= J[:, :2].mean(axis=0)
    a = np.radians(facing_deg)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    return J @ R.T + np.array([at[0], at[1], 0.0])


def in_sensor(J: np.ndarray, T: np.ndarray) -> np.ndarray:
    Ti = np.linalg.inv(T)
    return J @ Ti[:3, :3].T + Ti[:3, 3]


def as_v1(J25: np.ndarray) -> np.ndarray:
    return np.stack([J25[KINECT_V2.role_index(r)] for r in
                     [{v: k for k, v in KINECT_V1.roles.items()}[j] for j in KINECT_V1.joints]])


def walking_offset(k: int) -> np.ndarray:
    return np.array([0.04 * k, 0.0, 0.0])  # 1.2 m/s at 30 fps


# ----------------------------------------------------------------------- in-process


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    s = Settings(data_dir=tmp_path, viewer_enabled=False, node_token=NODE_TOKEN,
                 admin_password=PW, clock_ping_interval_s=0.05)
    with TestClient(create_app(s)) as c:
        r = c.post("/api/auth/login", json={"username": "admin", "password": PW})
        c.headers["Authorization"] = f"Bearer {r.json()['token']}"
        yield c


def _hello(ws: Any, node_id: str, T: np.ndarray, js: JointSet) -> None:
    ws.send_text(dump(Hello(node_id=node_id, token=NODE_TOKEN, agent_started=1.0,
                            sensor=SensorInfo(model="scripted", joint_set=js.name,
                                              T_world_sensor=T.tolist()))))
    while True:  # answer one ping so the server knows the node clock (offset 0)
        m = json.loads(ws.receive_text())
        if m["type"] == "ping":
            t = time.time()
            ws.send_text(dump(Pong(seq=m["seq"], t1=m["t1"], t2=t, t3=t)))
            return


def _wait(cond: Callable[[], Any], timeout: float, what: str) -> Any:
    deadline = time.time() + timeout
    while time.time() < deadline:
        v = cond()
        if v:
            return v
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def test_my_routes_need_login(tmp_path: Path) -> None:
    s = Settings(data_dir=tmp_path, viewer_enabled=False, admin_password=PW)
    with TestClient(create_app(s)) as c:
        for m, p in (("GET", "/api/kscc/sources"), ("GET", "/api/kscc/session"),
                     ("POST", "/api/kscc/session"), ("POST", "/api/kscc/shares"),
                     ("GET", "/api/kscc/active-area"), ("GET", "/api/kscc/trapezoid"),
                     ("DELETE", "/api/kscc/session"), ("POST", "/api/imu/sessions")):
            assert c.request(m, p, json={}).status_code == 401, p


def test_trapezoid_presets(client: TestClient) -> None:
    d = client.get("/api/kscc/trapezoid", params={"height_m": 1.0}).json()
    v1 = d["presets"]["kinect_v1"]["trapezoid"]
    # seed 004 at 1 m: 254 cm, 400 cm, "bases" (half widths) 138 and 217 cm
    assert v1["near_m"] == pytest.approx(2.54, abs=0.01)
    assert v1["far_m"] == pytest.approx(4.00, abs=0.01)
    assert v1["near_half_width_m"] == pytest.approx(1.38, abs=0.01)
    assert v1["far_half_width_m"] == pytest.approx(2.17, abs=0.01)
    for key in ("kinect_v2", "azure_nfov"):
        t = d["presets"][key]["trapezoid"]
        assert 0 < t["near_m"] < t["far_m"] and t["near_width_m"] < t["far_width_m"]
    r = client.get("/api/kscc/trapezoid", params={"height_m": -1})
    assert r.status_code == 422 and "height_m" in r.json()["detail"]


def test_live_calibration_progress_and_comparison(client: TestClient) -> None:
    T1 = sensor_pose((0.0, 0.0, 1.0), 0.0, -5.0)        # looks along +X, tilted down
    T2 = sensor_pose((6.0, 3.0, 1.3), 200.0, 0.0)       # across the room, other way
    person = standing_person((3.0, 0.4), 160.0)
    rng = np.random.default_rng(0)
    st = np.full((1, 25), 2, np.uint8)
    with client.websocket_connect("/ws/node") as w1, client.websocket_connect("/ws/node") as w2:
        _hello(w1, "S1", T1, KINECT_V2)
        _hello(w2, "S2", T2, KINECT_V2)
        # bad input first: the same node twice, an unknown node
        r = client.post("/api/kscc/session", json={"a": {"kind": "node", "node_id": "S1"},
                                                    "b": {"kind": "node", "node_id": "S1"}})
        assert r.status_code == 400 and "two different" in r.json()["detail"]
        r = client.post("/api/kscc/session", json={"a": {"kind": "node", "node_id": "S1"},
                                                    "b": {"kind": "node", "node_id": "S9"}})
        assert r.status_code == 400 and "S9" in r.json()["detail"]
        r = client.post("/api/kscc/session", json={"a": {"kind": "node", "node_id": "S1"},
                                                    "b": {"kind": "node", "node_id": "S2"},
                                                    "countdown_s": 0})
        assert r.status_code == 200, r.text
        assert {s["node_id"] for s in client.get("/api/kscc/sources").json()} == {"S1", "S2"}
        t0 = time.time()
        seen: set[str] = set()

        def send(k: int, J: np.ndarray) -> None:
            t = t0 + k / 30.0
            noise = rng.normal(0, 0.002, J.shape)
            w1.send_bytes(encode_skeletons(k, t, in_sensor(J + noise, T1)[None], st))
            w2.send_bytes(encode_skeletons(k, t, in_sensor(J + noise, T2)[None], st))

        # the user walks in: never collected; then stands still: collected, done
        for k in range(45):
            send(k, person + walking_offset(k) - walking_offset(45))
        s = _wait(lambda: (d := client.get("/api/kscc/session").json())["sides"]["a"]["frames"]
                  >= 45 and d, 10, "45 frames")
        a = s["sides"]["a"]
        seen.add(a["progress"]["state"])
        assert a["progress"]["state"] in ("waiting", "moved") and not a["calibrated"]
        for k in range(45, 45 + 60):
            send(k, person)
        s = _wait(lambda: (d := client.get("/api/kscc/session").json())["sides"]["a"]["frames"]
                  >= 105 and d, 10, "105 frames")
        prog = s["sides"]["a"]["progress"]
        seen.add(prog["state"])
        assert prog["state"] == "collecting" and 0 < prog["n_collected"] < 120
        assert prog["n_required"] == 120
        for k in range(105, 105 + 90):
            send(k, person)
        s = _wait(lambda: (d := client.get("/api/kscc/session").json())["sides"]["b"]
                  ["calibrated"] and d["sides"]["a"]["calibrated"] and d, 10, "calibration")
        seen.add("done")
        for k in range(195, 260):  # both users raise and lower an arm: compared live
            J = person.copy()
            J[KINECT_V2.index("HandLeft"), 2] += 0.3 * np.sin(k / 10)
            send(k, J)
        s = _wait(lambda: (d := client.get("/api/kscc/session").json())["comparison"]
                  ["ready"] and d["sides"]["a"]["frames"] >= 260 and d["sides"]["b"]["frames"]
                  >= 260 and d, 10, "comparison")
    assert {"collecting", "done"} <= seen
    a, b = s["sides"]["a"], s["sides"]["b"]
    # the same person seen from two sensors facing different ways lands at one place
    Ua = np.array(a["skeleton"]["positions"], dtype=float)
    Ub = np.array(b["skeleton"]["positions"], dtype=float)
    assert np.nanmax(np.linalg.norm(Ua - Ub, axis=1)) < 0.02
    # same world facing; each sensor saw the user at its own initial angle (paper's θ)
    assert a["calibration"]["heading_deg"] == pytest.approx(b["calibration"]["heading_deg"],
                                                           abs=1.0)
    assert abs(a["calibration"]["initial_angle_deg"]
               - b["calibration"]["initial_angle_deg"]) > 10
    c = s["comparison"]
    assert c["similarity"] > 85 and "apart on average" in c["meaning"]
    assert len(c["joints"]) == 25 and len(c["per_joint_m"]) == 25
    assert len(c["times"]) == len(c["mean_m"]) > 20
    assert np.nanmax(np.array(c["mean_m"], dtype=float)) < 0.02


def test_user_who_keeps_moving_and_mismatched_joint_sets(client: TestClient) -> None:
    T1 = sensor_pose((0.0, 0.0, 1.0), 0.0)
    T3 = sensor_pose((0.0, 2.0, 1.0), -30.0)
    person = standing_person((3.0, 0.5), 180.0)
    st25 = np.full((1, 25), 2, np.uint8)
    st20 = np.full((1, 20), 2, np.uint8)
    with client.websocket_connect("/ws/node") as w1, client.websocket_connect("/ws/node") as w3:
        _hello(w1, "S1", T1, KINECT_V2)
        _hello(w3, "K1", T3, KINECT_V1)
        r = client.post("/api/kscc/session", json={"a": {"kind": "node", "node_id": "S1"},
                                                    "b": {"kind": "node", "node_id": "K1"},
                                                    "countdown_s": 0})
        assert r.status_code == 200
        t0 = time.time()
        # S1's user keeps stepping back and forth every second: restarts, message says so
        for k in range(300):
            t = t0 + k / 30.0
            step = np.array([0.3 * ((k // 30) % 2), 0.0, 0.0])
            w1.send_bytes(encode_skeletons(k, t, in_sensor(person + step, T1)[None], st25))
            w3.send_bytes(encode_skeletons(k, t, in_sensor(as_v1(person), T3)[None], st20))
        s = _wait(lambda: (d := client.get("/api/kscc/session").json())["sides"]["a"]["frames"]
                  >= 300 and d["sides"]["b"]["frames"] >= 300 and d, 15, "300 frames")
        a = s["sides"]["a"]
        assert not a["calibrated"] and a["restarts"] >= 3
        assert "stand still" in a["message"]
        assert s["sides"]["b"]["calibrated"] and s["sides"]["b"]["joint_set"] == "kinect_v1"
        # a stands still now; then the comparison explains the joint-set mismatch
        for k in range(300, 450):
            t = t0 + k / 30.0
            w1.send_bytes(encode_skeletons(k, t, in_sensor(person, T1)[None], st25))
            w3.send_bytes(encode_skeletons(k, t, in_sensor(as_v1(person), T3)[None], st20))
        s = _wait(lambda: (d := client.get("/api/kscc/session").json())["sides"]["a"]
                  ["calibrated"] and d["sides"]["a"]["frames"] >= 450 and d, 15, "calibration")
        c = s["comparison"]
        assert not c["ready"] and c["mismatch"] and "share" in c["message"]
        # with by_role the shared joints are compared
        r = client.post("/api/kscc/session", json={"a": {"kind": "node", "node_id": "S1"},
                                                    "b": {"kind": "node", "node_id": "K1"},
                                                    "countdown_s": 0, "by_role": True})
        t0 = time.time() + 20
        for k in range(200):
            t = t0 + k / 30.0
            w1.send_bytes(encode_skeletons(k, t, in_sensor(person, T1)[None], st25))
            w3.send_bytes(encode_skeletons(k, t, in_sensor(as_v1(person), T3)[None], st20))
        s = _wait(lambda: (d := client.get("/api/kscc/session").json())["comparison"]["ready"]
                  and d["sides"]["a"]["frames"] >= 200 and d, 15, "by-role comparison")
        assert len(s["comparison"]["joints"]) == len([r for r in KINECT_V2.roles
                                                      if r in KINECT_V1.roles])
        assert s["comparison"]["similarity"] > 70
    assert client.get("/api/kscc/session").json()["running"] is True
    assert client.delete("/api/kscc/session").status_code == 204
    _assert_idle(client)
    # a restart with nothing to restart is still refused, saying what to do
    r = client.post("/api/kscc/session/restart", json={"side": "both"})
    assert r.status_code == 404 and "start one" in r.json()["detail"], r.text


def _assert_idle(client: httpx.Client) -> None:
    """No session running is a normal state: 200 with an explicit idle answer (the page
    polls it; a 404 would be logged by the browser on every poll)."""
    r = client.get("/api/kscc/session")
    assert r.status_code == 200, r.text
    d = r.json()
    assert d["running"] is False and d["sides"] is None and d["comparison"] is None, d
    assert "start one" in d["message"]


def test_active_area_per_node(client: TestClient) -> None:
    T = sensor_pose((0.0, 0.0, 1.0), 0.0, 0.0)
    with client.websocket_connect("/ws/node") as w1:
        _hello(w1, "S1", T, KINECT_V2)
        rows = client.get("/api/kscc/active-area").json()
    (row,) = rows
    assert row["node_id"] == "S1" and row["height_m"] == pytest.approx(1.0)
    assert row["tilt_deg"] == pytest.approx(0.0, abs=1e-6)
    assert row["presets"]["kinect_v1"]["trapezoid"]["near_m"] == pytest.approx(2.54, abs=0.01)
    poly = np.array(row["polygon"])
    assert poly.shape[0] >= 4 and poly[:, 0].min() > 0.5  # in front of the sensor


# ------------------------------------------------------------------- two servers


class Site:
    """A real server (uvicorn on a free loopback port, in a thread) with a logged-in client."""

    def __init__(self, tmp: Path, peers: list[str] | None = None) -> None:
        import httpx

        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            self.port = int(s.getsockname()[1])
        settings = Settings(data_dir=tmp, viewer_enabled=False, node_token=NODE_TOKEN,
                            admin_password=PW, clock_ping_interval_s=0.2,
                            kscc_peers=peers or [])
        self.server = uvicorn.Server(uvicorn.Config(create_app(settings), host="127.0.0.1",
                                                    port=self.port, log_level="warning"))
        self.thread = threading.Thread(target=self.server.run, daemon=True)
        self.thread.start()
        _wait(lambda: self.server.started, 20, "server start")
        self.base = f"http://127.0.0.1:{self.port}"
        self.http = httpx.Client(base_url=self.base, timeout=10)
        tok = self.http.post("/api/auth/login", json={"username": "admin", "password": PW})
        self.http.headers["Authorization"] = f"Bearer {tok.json()['token']}"

    def close(self) -> None:
        self.http.close()
        self.server.should_exit = True
        self.thread.join(10)


class ScriptedNode:
    """A node process stand-in: a websocket client streaming a still person at 30 fps."""

    def __init__(self, site: Site, node_id: str, T: np.ndarray, person: np.ndarray) -> None:
        self.site, self.node_id, self.T, self.person = site, node_id, T, person
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self) -> None:
        from websockets.sync.client import connect

        rng = np.random.default_rng(abs(hash(self.node_id)) % 1000)
        st = np.full((1, 25), 2, np.uint8)
        with connect(f"ws://127.0.0.1:{self.site.port}/ws/node") as ws:
            info = SensorInfo(model="scripted", T_world_sensor=self.T.tolist())
            ws.send(dump(Hello(node_id=self.node_id, token=NODE_TOKEN, agent_started=1.0,
                               sensor=info)))
            k = 0
            t_next = time.time()
            while not self.stop.is_set():
                try:
                    while True:  # answer pings so the server measures this clock
                        m = json.loads(ws.recv(timeout=0))
                        if m["type"] == "ping":
                            t = time.time()
                            ws.send(dump(Pong(seq=m["seq"], t1=m["t1"], t2=t, t3=t)))
                except TimeoutError:
                    pass
                J = self.person + rng.normal(0, 0.002, self.person.shape)
                ws.send(encode_skeletons(k, time.time(), in_sensor(J, self.T)[None], st))
                k += 1
                t_next += 1 / 30
                time.sleep(max(0.0, t_next - time.time()))


@pytest.fixture
def two_sites(tmp_path: Path) -> Iterator[tuple[Site, Site, list[ScriptedNode]]]:
    b = Site(tmp_path / "b")
    a = Site(tmp_path / "a", peers=[b.base])  # site A may link to site B only
    nodes: list[ScriptedNode] = []
    yield a, b, nodes
    for n in nodes:
        n.stop.set()
        n.thread.join(5)
    a.close()
    b.close()


def test_two_site_link(two_sites: tuple[Site, Site, list[ScriptedNode]]) -> None:
    site_a, site_b, nodes = two_sites
    T_a = sensor_pose((0.0, 0.0, 1.0), 0.0)
    T_b = sensor_pose((4.0, -3.0, 0.9), 120.0)
    # two different people standing differently at two sites, same posture
    nodes.append(ScriptedNode(site_a, "S1", T_a, standing_person((2.8, 0.3), 190.0)))
    nodes.append(ScriptedNode(site_b, "R1", T_b, standing_person((2.5, 0.2), 250.0)))
    _wait(lambda: site_b.http.get("/api/nodes/R1/skeleton").status_code == 200, 15, "R1")
    _wait(lambda: site_a.http.get("/api/nodes/S1/skeleton").status_code == 200, 15, "S1")
    # site B shares R1; short tokens are refused
    r = site_b.http.post("/api/kscc/shares", json={"node_id": "R1", "token": "short"})
    assert r.status_code == 422
    r = site_b.http.post("/api/kscc/shares", json={"node_id": "R1", "token": LINK_TOKEN})
    assert r.status_code == 201
    remote = {"kind": "remote", "node_id": "R1", "url": site_b.base}
    # a server that is not in site A's kscc_peers: refused before any connection, saying
    # which setting allows it
    for url in (f"http://127.0.0.1:{site_b.port + 1}", f"https://127.0.0.1:{site_b.port}",
                "http://10.11.12.13:8000"):
        r = site_a.http.post("/api/kscc/session", json={
            "a": {"kind": "node", "node_id": "S1"},
            "b": {**remote, "url": url, "token": LINK_TOKEN}, "countdown_s": 0})
        assert r.status_code == 403, r.text
        assert "kscc_peers" in r.json()["detail"] and url in r.json()["detail"]
    _assert_idle(site_a.http)  # nothing started
    # wrong token: refused, and the page is told why
    r = site_a.http.post("/api/kscc/session", json={
        "a": {"kind": "node", "node_id": "S1"},
        "b": {**remote, "token": "wrong-token-0123456789"}, "countdown_s": 0})
    assert r.status_code == 200, r.text
    s = _wait(lambda: (d := site_a.http.get("/api/kscc/session").json())["sides"]["b"]["link"]
              == "refused" and d, 15, "refusal")
    assert "refused" in s["sides"]["b"]["message"] and s["sides"]["b"]["frames"] == 0
    # right token: R1's skeletons stream to site A, both calibrate, compared
    r = site_a.http.post("/api/kscc/session", json={
        "a": {"kind": "node", "node_id": "S1"}, "b": {**remote, "token": LINK_TOKEN},
        "countdown_s": 0})
    assert r.status_code == 200
    s = _wait(lambda: (d := site_a.http.get("/api/kscc/session").json())["comparison"]["ready"]
              and d, 30, "two-site comparison")
    b = s["sides"]["b"]
    assert b["link"] == "connected" and b["frames"] >= 120 and b["calibrated"]
    assert b["model"] == "scripted" and b["joint_set"] == "kinect_v2"
    assert s["comparison"]["similarity"] > 85, s["comparison"]["meaning"]
    # site B stops sharing: the link closes and A says the other site is gone or refuses
    assert site_b.http.delete("/api/kscc/shares/R1").status_code == 204
    s = _wait(lambda: (d := site_a.http.get("/api/kscc/session").json())["sides"]["b"]["link"]
              in ("refused", "unreachable") and d, 15, "unshare")
    assert site_a.http.delete("/api/kscc/session").status_code == 204


def test_peer_matching() -> None:
    from app.server.kscc_link import PeerNotAllowedError, check_peer

    peers = ["https://lab-b.example.org:8443", "10.0.0.5:8000", "Lab-C.example.org", "bad:port:x"]
    ok = {"https://lab-b.example.org:8443": "wss://lab-b.example.org:8443/api/kscc/link",
          "wss://LAB-B.example.org:8443/": "wss://LAB-B.example.org:8443/api/kscc/link",
          "http://10.0.0.5:8000": "ws://10.0.0.5:8000/api/kscc/link",
          "https://10.0.0.5:8000": "wss://10.0.0.5:8000/api/kscc/link",
          "http://lab-c.example.org:9000": "ws://lab-c.example.org:9000/api/kscc/link"}
    for url, ws in ok.items():
        assert check_peer(url, peers) == ws
    for url in ("http://lab-b.example.org:8443",  # scheme differs from the entry
                "https://lab-b.example.org",  # default port 443 ≠ 8443
                "http://10.0.0.5:8001", "http://10.0.0.6:8000",
                "http://10.0.0.5:8000@evil.example.org:8000",  # user-info trick
                "https://lab-b.example.org.evil.net:8443"):
        with pytest.raises(PeerNotAllowedError, match="kscc_peers"):
            check_peer(url, peers)
    with pytest.raises(PeerNotAllowedError, match="Allowed now: none"):
        check_peer("http://10.0.0.5:8000", [])


def test_3d_view_gets_active_areas_and_both_users(tmp_path: Path) -> None:
    s = Settings(data_dir=tmp_path, viewer_enabled=True, viewer_port=0, node_token=NODE_TOKEN,
                 admin_password=PW, clock_ping_interval_s=0.05)
    T1 = sensor_pose((0.0, 0.0, 1.0), 0.0)
    T2 = sensor_pose((6.0, 0.0, 1.0), 180.0)
    person = standing_person((3.0, 0.0), 180.0)
    st = np.full((1, 25), 2, np.uint8)
    with TestClient(create_app(s)) as c:
        r = c.post("/api/auth/login", json={"username": "admin", "password": PW})
        c.headers["Authorization"] = f"Bearer {r.json()['token']}"
        scene = c.app.state.viewer.server.scene  # type: ignore[attr-defined]
        with c.websocket_connect("/ws/node") as w1, c.websocket_connect("/ws/node") as w2:
            _hello(w1, "S1", T1, KINECT_V2)
            _hello(w2, "S2", T2, KINECT_V2)
            # drawn from server start as the nodes connect, before any KSCC call
            _wait(lambda: {"/active_area/S1", "/active_area/S2"}
                  <= set(scene._handle_from_node_name), 5, "active areas at start")
            assert not hasattr(c.app.state, "kscc")  # type: ignore[attr-defined]
            layer = c.app.state.active_areas  # type: ignore[attr-defined]
            layer.toggle.value = False  # the "Active areas" checkbox of the 3D view
            _wait(lambda: not scene._handle_from_node_name["/active_area/S1"].visible, 5,
                  "areas hidden by the toggle")
            layer.toggle.value = True
            _wait(lambda: scene._handle_from_node_name["/active_area/S2"].visible, 5,
                  "areas shown again")
            assert len(c.get("/api/kscc/active-area").json()) == 2
            c.post("/api/kscc/session", json={"a": {"kind": "node", "node_id": "S1"},
                                              "b": {"kind": "node", "node_id": "S2"},
                                              "countdown_s": 0})
            t0 = time.time()
            for k in range(170):
                t = t0 + k / 30.0
                w1.send_bytes(encode_skeletons(k, t, in_sensor(person, T1)[None], st))
                w2.send_bytes(encode_skeletons(k, t, in_sensor(person, T2)[None], st))
                if k >= 130:
                    time.sleep(0.11)  # the 3D view is redrawn at most 10 times a second
            _wait(lambda: c.get("/api/kscc/session").json()["comparison"]["ready"], 10,
                  "comparison")
            _wait(lambda: {"/kscc/side/a", "/kscc/side/b", "/kscc/overlay/b"}
                  <= set(scene._handle_from_node_name), 10, "the 3D panels")


def test_missing_shoulders_are_explained(client: TestClient) -> None:
    T1 = sensor_pose((0.0, 0.0, 1.0), 0.0)
    T2 = sensor_pose((0.0, 1.0, 1.0), -20.0)
    person = standing_person((3.0, 0.5), 180.0)
    st = np.full((1, 25), 2, np.uint8)
    hidden = st.copy()
    for j in ("ShoulderLeft", "ShoulderRight"):
        hidden[0, KINECT_V2.index(j)] = 0  # NOT_TRACKED
    with client.websocket_connect("/ws/node") as w1, client.websocket_connect("/ws/node") as w2:
        _hello(w1, "S1", T1, KINECT_V2)
        _hello(w2, "S2", T2, KINECT_V2)
        client.post("/api/kscc/session", json={"a": {"kind": "node", "node_id": "S1"},
                                               "b": {"kind": "node", "node_id": "S2"},
                                               "countdown_s": 0})
        t0 = time.time()
        for k in range(60):
            t = t0 + k / 30.0
            w1.send_bytes(encode_skeletons(k, t, in_sensor(person, T1)[None], hidden))
            w2.send_bytes(encode_skeletons(k, t, in_sensor(person, T2)[None], st))
        s = _wait(lambda: (d := client.get("/api/kscc/session").json())["sides"]["a"]["frames"]
                  >= 60 and d["sides"]["b"]["frames"] >= 60 and d, 10, "60 frames")
    a, b = s["sides"]["a"], s["sides"]["b"]
    assert a["progress"]["state"] == "waiting" and a["progress"]["n_collected"] == 0
    assert "shoulder" in a["message"].lower()
    assert b["progress"]["state"] == "collecting" and b["progress"]["n_collected"] > 30
    assert not s["comparison"]["ready"] and "calibrated first" in s["comparison"]["message"]
