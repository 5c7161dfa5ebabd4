"""Calibration API in-process: marker sheet, saved versions, restore, bumped-tripod check."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from app.server import calibration as cal
from engine.calibration.corners3d import Observation
from engine.calibration.pipeline import calibrate
from engine.geometry import transform_points
from engine.sim.rig import default_avenue_rig, marker_visibility


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    return Settings(data_dir=tmp_path, viewer_enabled=False, node_token="cal-test-token",
                    admin_password="cal-pw")


@pytest.fixture
def client(settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(settings)) as c:
        r = c.post("/api/auth/login", json={"username": "admin", "password": "cal-pw"})
        c.headers["Authorization"] = f"Bearer {r.json()['token']}"
        yield c


def _result():  # type: ignore[no-untyped-def]
    rig = default_avenue_rig(0)
    obs = []
    for mid, sids in marker_visibility(rig).items():
        for sid in sids:
            c = transform_points(rig.sensor(sid).T_sensor_world, rig.marker(mid).corners_world())
            obs.append(Observation(sid, mid, True, corners=c,
                                   cov=np.tile(np.eye(3) * 1e-6, (4, 1, 1)), distance_m=3.0))
    return calibrate(obs, 0.4)


def test_needs_login(settings: Settings) -> None:
    with TestClient(create_app(settings)) as c:
        assert c.get("/api/calibration").status_code == 401
        assert c.get("/api/calibration/markers.pdf").status_code == 401


def test_marker_sheet_pdf(client: TestClient) -> None:
    r = client.get("/api/calibration/markers.pdf", params={"ids": "1-4", "size": 0.1})
    assert r.status_code == 200 and r.content.startswith(b"%PDF")
    assert r.headers["content-type"] == "application/pdf"
    bad = client.get("/api/calibration/markers.pdf", params={"ids": "4-1"})
    assert bad.status_code == 400 and "reversed" in bad.text
    assert client.get("/api/calibration/markers.pdf", params={"ids": "0-99"}).status_code == 400
    assert client.get("/api/calibration/markers.pdf", params={"size": 3}).status_code == 422


def test_capture_form_defaults(client: TestClient, settings: Settings) -> None:
    """The wizard starts from the markers the server expects: the sheet's defaults, the
    simulated room's when only simulated sensors are connected, the active calibration's."""
    from app.nodes.protocol import SensorInfo

    async def send(_: str) -> None:
        return None

    d = client.get("/api/calibration/defaults").json()
    assert d == {"marker_ids": "1-8", "marker_size_m": 0.20,
                 "source": "the printed sheet's default"}
    registry = client.app.state.hub.registry  # type: ignore[attr-defined]
    registry.connect("S1", "sim", SensorInfo(), send, restarted=False)
    d = client.get("/api/calibration/defaults").json()
    assert d["marker_size_m"] == 0.40 and d["marker_ids"] == "1-8"
    assert d["source"] == "the simulated demo room"
    registry.connect("K1", "kinect", SensorInfo(), send, restarted=False)
    assert client.get("/api/calibration/defaults").json()["marker_size_m"] == 0.20
    res = _result()
    res.marker_sizes = {1: 0.3, 2: 0.3, 3: 0.3, 5: 0.25}
    cal.save(settings.data_dir, res)
    d = client.get("/api/calibration/defaults").json()
    assert d == {"marker_ids": "1-3,5", "marker_size_m": 0.3, "source": "calibration 1"}


def test_versions_restore_and_check(client: TestClient, settings: Settings) -> None:
    assert client.get("/api/calibration").json() == []
    r = client.get("/api/calibration/active")
    assert r.status_code == 400 and "no calibration" in r.text
    res = _result()
    assert cal.save(settings.data_dir, res) == 1
    assert cal.save(settings.data_dir, res) == 2
    rows = client.get("/api/calibration").json()
    assert [x["version"] for x in rows] == [2, 1]
    assert rows[0]["sensors"] == ["S1", "S2", "S3", "S4", "S5", "S6"]
    one = client.get("/api/calibration/1").json()
    assert one["version"] == 1 and set(one["T_world_sensor"]) == set(rows[0]["sensors"])
    assert client.get("/api/calibration/9").status_code == 400
    r = client.post("/api/calibration/1/restore").json()
    assert r == {"version": 3, "restored_from": 1, "applied_to": []}
    assert client.get("/api/calibration/active").json()["meta"]["restored_from"] == 1
    poses = {s: np.asarray(T).tolist() for s, T in res.T_world_sensor.items()}
    assert client.post("/api/calibration/check", json={"T_world_sensor": poses}).json()["ok"]
    poses["S4"][0][3] += 0.02
    moved = client.post("/api/calibration/check", json={"T_world_sensor": poses}).json()
    assert [m["sensor"] for m in moved["moved"]] == ["S4"] and not moved["ok"]
    r = client.post("/api/calibration/check", json={"T_world_sensor": {"S1": [[1, 0], [0, 1]]}})
    assert r.status_code == 400 and "4×4" in r.text


def test_active_calibration_applied_to_node_streams(client: TestClient,
                                                    settings: Settings) -> None:
    from app.nodes.protocol import SensorInfo

    async def send(_: str) -> None:
        return None

    registry = client.app.state.hub.registry  # type: ignore[attr-defined]
    registry.connect("S1", "sim", SensorInfo(), send, restarted=False)
    res = _result()
    cal.save(settings.data_dir, res)
    assert client.post("/api/calibration/apply").json() == {"applied_to": ["S1"]}
    assert np.allclose(registry.get("S1").sensor.T_world_sensor, res.T_world_sensor["S1"])
    # a node connecting later (reporting its own pose) gets the calibrated one
    registry.connect("S2", "sim", SensorInfo(), send, restarted=False)
    assert np.allclose(registry.get("S2").sensor.T_world_sensor, res.T_world_sensor["S2"])
    poses = cal.active_poses(settings.data_dir)
    assert poses["S3"]["source"] == "calibration" and poses["S3"]["calibration_version"] == "1"


def test_accept_and_restore_take_effect_on_live_poses_and_lenses_at_once(
        client: TestClient, settings: Settings) -> None:
    """Accepting a capture or restoring a version changes, without the nodes reconnecting,
    each connected node's pose and the depth lens the live cloud draws it through — also
    for a node the new active version leaves out: its reported pose and announced lens
    come back instead of staying the previous version's."""
    from app.api.routes.calibration import _manager
    from app.nodes.protocol import CameraLens, SensorInfo, SensorLens
    from app.server.calibration import CaptureJob
    from engine.calibration.pipeline import CalibrationResult

    async def send(_: str) -> None:
        return None

    K = [[365.0, 0.0, 255.5], [0.0, 365.0, 211.5], [0.0, 0.0, 1.0]]
    factory, lens_a, lens_b = ((-0.1, 0.02, 0.0, 0.0, 0.0), (-0.12, 0.03, 0.0008, -0.0005, 0.0),
                               (-0.05, 0.01, 0.0, 0.0, 0.0))

    def at(x: float) -> np.ndarray:
        T = np.eye(4)
        T[0, 3] = x
        return T

    def version(poses: dict[str, np.ndarray], dist: tuple[float, ...]) -> CalibrationResult:
        cams = {s: {"depth": {"size": [512, 424], "K": K, "dist": list(dist)}} for s in poses}
        return CalibrationResult(poses, poses, {1: np.eye(4)}, {1: 0.4},
                                 {s: 0.001 for s in poses}, [], [], meta={"cameras": cams})

    app = client.app
    hub, live = app.state.hub, app.state.live  # type: ignore[attr-defined]
    hub.registry.listeners.append(live._on_nodes)  # as it does with the 3D view on
    s1 = hub.registry.connect("S1", "k4a", SensorInfo(depth_K=K, depth_size=(512, 424),
                                                      T_world_sensor=at(0.5).tolist()),
                              send, True)
    s1.lens = SensorLens(source="factory calibration",
                         depth=CameraLens(size=(512, 424), K=K, dist=list(factory)))
    assert cal.save(settings.data_dir, version({"S1": at(1.0)}, lens_a)) == 1
    assert client.post("/api/calibration/apply").json() == {"applied_to": ["S1"]}

    def now() -> tuple[float, tuple[float, ...] | None]:
        return s1.sensor.T_world_sensor[0][3], live._depth_lens.get("S1")

    assert now() == (1.0, lens_a)
    mgr = _manager(app, hub, settings.data_dir)
    for job_id, poses, dist in ((41, {"S1": at(2.0)}, lens_b), (42, {"S9": at(3.0)}, lens_a)):
        mgr.jobs[job_id] = CaptureJob(job_id, "calibrate", list(poses), 1, {}, state="done",
                                      result=version(poses, dist))
    r = client.post("/api/calibration/captures/41/accept")
    assert r.status_code == 200 and r.json() == {"version": 2, "applied_to": ["S1"]}
    assert now() == (2.0, lens_b)
    r = client.post("/api/calibration/1/restore").json()
    assert r == {"version": 3, "restored_from": 1, "applied_to": ["S1"]}
    assert now() == (1.0, lens_a)
    # a version without S1: its own pose and its announced lens, not version 1's
    assert client.post("/api/calibration/captures/42/accept").json()["applied_to"] == []
    assert now() == (0.5, factory)
    assert client.post("/api/calibration/2/restore").json()["applied_to"] == ["S1"]
    assert now() == (2.0, lens_b)
    assert client.post("/api/calibration/4/restore").json()["applied_to"] == []
    assert now() == (0.5, factory)
