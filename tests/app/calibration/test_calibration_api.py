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
