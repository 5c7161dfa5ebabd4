"""In-process tests of the data API, migrations, state logic and export round trips."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import ezc3d
import numpy as np
import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.api.routes import _reference
from app.config import Settings
from app.db.base import Base, alembic_head, make_engine
from app.main import create_app
from app.nodes.protocol import encode_skeletons
from app.nodes.store import NodeStore
from app.server.datasync import part_state, recording_state
from app.server.recording import Part, Recording
from app.server.storage import (
    StorageLayout,
    export_skeleton,
    read_part_skeleton,
    uniform_series,
)
from app.transfer import TransferSink, build_manifest, read_chunk
from engine.io.c3d import read_c3d
from engine.io.csv import read_skeleton_csv
from engine.io.trc import read_trc
from engine.skeleton import KINECT_V2, TrackingState


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    s = Settings(data_dir=tmp_path, viewer_enabled=False, node_token="test-node-token",
                 admin_password="secret-pw")
    with TestClient(create_app(s)) as c:
        r = c.post("/api/auth/login", json={"username": "admin", "password": "secret-pw"})
        c.headers["Authorization"] = f"Bearer {r.json()['token']}"
        yield c


def test_migrations_new_and_existing_database(tmp_path: Path) -> None:
    eng = make_engine(tmp_path / "new.sqlite3")
    with eng.connect() as c:
        version = c.execute(sa.text("select version_num from alembic_version")).scalar()
        assert version == alembic_head()
    eng.dispose()
    # a database whose tables were made by create_all (no alembic_version) is adopted
    import app.db.data  # noqa: F401
    old = sa.create_engine(f"sqlite:///{tmp_path / 'old.sqlite3'}")
    Base.metadata.create_all(old)
    with old.begin() as c:
        c.execute(sa.text("insert into projects (name, description, created_at) "
                          "values ('kept', '', '2026-01-01')"))
    old.dispose()
    eng = make_engine(tmp_path / "old.sqlite3")
    with eng.connect() as c:
        version = c.execute(sa.text("select version_num from alembic_version")).scalar()
        assert version == alembic_head()
        assert c.execute(sa.text("select name from projects")).scalar() == "kept"
    eng.dispose()


def test_crud_validation_and_confirmation(client: TestClient) -> None:
    assert TestClient(client.app).get("/api/projects").status_code == 401
    p = client.post("/api/projects", json={"name": "Study"}).json()
    assert client.post("/api/projects", json={"name": "Study"}).status_code == 409
    body = {"project_id": p["id"], "code": "P001", "height_m": 1.8, "sex": "male",
            "birth_year": 1970}
    s = client.post("/api/subjects", json=body).json()
    assert s["code"] == "P001" and s["bytes_on_server"] == 0
    assert client.post("/api/subjects", json=body).status_code == 409
    for bad in ({"code": "Jane Doe"}, {"code": "../x"}, {"height_m": 5.0},
                {"sex": "x"}):
        r = client.post("/api/subjects", json={**body, "code": "P002", **bad})
        assert r.status_code == 422, bad
    r = client.post("/api/subjects", json={**body, "code": "P002", "birth_year": 1800})
    assert r.status_code == 422 and "1900" in r.json()["detail"]
    assert client.post("/api/subjects", json={**body, "project_id": 999}).status_code == 404
    r = client.patch(f"/api/subjects/{s['id']}", json={"leg_length_m": 0.92, "notes": "ok"})
    assert r.json()["leg_length_m"] == 0.92 and r.json()["height_m"] == 1.8
    sess = client.post("/api/sessions", json={"subject_id": s["id"], "label": "baseline"})
    assert sess.status_code == 201
    # no node is connected: a recording cannot start, with a message saying why
    r = client.post(f"/api/sessions/{sess.json()['id']}/recordings", json={})
    assert r.status_code == 409 and "no connected node" in r.json()["detail"]
    assert client.get("/api/storage/recordings/R1").status_code == 404
    assert client.get("/api/exports/R1/skeleton").status_code == 404
    r = client.post(f"/api/subjects/{s['id']}/delete", json={"confirm": "p001"})
    assert r.status_code == 400 and "'P001'" in r.json()["detail"]
    r = client.post(f"/api/subjects/{s['id']}/delete", json={"confirm": "P001"})
    assert r.status_code == 200
    assert client.get(f"/api/subjects/{s['id']}").status_code == 404
    usage = client.get("/api/storage").json()
    assert usage["disk"]["free"] > 0 and usage["subjects"] == []


def test_part_and_recording_states() -> None:
    rec = Recording("R1", t_start=1.0, t_stop=None)
    assert recording_state(rec, {}) == ("recording", None)
    rec.t_stop = 2.0
    ok = Part("S1", state="complete", on_server=True, n_frames=10)
    assert part_state(ok, True) == ("complete", None)
    # a complete part keeps what happened on the way, not a transfer failure retried since
    noted = Part("S3", state="complete", on_server=True, n_frames=10,
                 reason="node S3 disconnected at 10:00:00 UTC during the recording; the node "
                        "kept recording")
    assert part_state(noted, True) == ("complete", noted.reason)
    retried = Part("S4", state="complete", on_server=True, n_frames=10,
                   reason="transfer failed (connection lost); retry")
    assert part_state(retried, True) == ("complete", None)
    # the server's copy vanished: never reported complete
    assert part_state(ok, False)[0] == "incomplete"
    failed = Part("S2", state="on_node", n_frames=10,
                  reason="transfer failed (server disk is full); retry")
    st = {"S1": part_state(ok, True), "S2": part_state(failed, False)}
    state, reason = recording_state(rec, st)
    assert state == "incomplete" and reason is not None and reason.startswith("S2: transfer")
    assert recording_state(rec, {"S1": ("on_node", None)})[0] == "on_nodes"
    assert recording_state(rec, {"S1": ("transferring", None),
                                 "S2": ("incomplete", "x")})[0] == "transferring"


def _make_part(tmp_path: Path, server: Path | None = None) -> Path:
    """A node part of 60 frames (two bodies, one hidden joint), copied through a sink
    into the data folder ``server`` (default ``tmp_path/server``)."""
    rng = np.random.default_rng(0)
    store = NodeStore(tmp_path / "node")
    w = store.create_part("R1", node_id="S1",
                          clock_start={"offset_s": 5.0, "drift": 0.0, "t_ref": 0.0})
    for k in range(60):
        pos = rng.normal(0, 0.3, (2, 25, 3)) + np.array([0, 0, 2.5])
        st = np.full((2, 25), TrackingState.TRACKED, np.uint8)
        st[1, :] = TrackingState.NOT_TRACKED  # a bystander: the subject is body 0
        st[0, 3] = TrackingState.NOT_TRACKED if k == 10 else TrackingState.TRACKED
        w.append(105.0 + k / 30, "skeleton", encode_skeletons(k, 105.0 + k / 30, pos, st))
    w.close()
    return _sink_part(store.root / "R1", "R1", "S1", server or tmp_path / "server")


def _sink_part(src: Path, rec_id: str, node: str, data_dir: Path) -> Path:
    """A node's closed part copied into the server's layout through the transfer sink
    (manifest, every chunk, sealed, finalised), as a transfer would; returns its folder."""
    m = build_manifest(src, rec_id, node, ["meta.json", "index.json", "frames.bin"])
    dest = StorageLayout(data_dir).part_dir(rec_id, node)
    sink = TransferSink(dest, m)
    for name, idx in sink.missing_chunks():
        sink.write_chunk(name, idx, read_chunk(src, m, name, idx))
    for f in m.files:
        sink.seal_file(f.name)
    sink.finalize()
    return dest


def test_read_part_and_round_trips(tmp_path: Path) -> None:
    part = _make_part(tmp_path)
    s = read_part_skeleton(part)
    assert len(s) == 60 and s.joint_set is KINECT_V2
    np.testing.assert_allclose(s.times, 100.0 + np.arange(60) / 30)  # server clock
    assert s.states[10, 3] == TrackingState.NOT_TRACKED and np.isnan(s.positions[10, 3]).all()
    (tmp_path / "x.csv").write_bytes(export_skeleton(s, "csv"))
    back = read_skeleton_csv(tmp_path / "x.csv")
    np.testing.assert_array_equal(back.times, s.times)
    np.testing.assert_allclose(back.positions, s.positions, atol=0, equal_nan=True)
    np.testing.assert_array_equal(back.states, s.states)
    u = uniform_series(s)
    assert np.allclose(np.diff(u.times), 1 / 30)
    (tmp_path / "x.c3d").write_bytes(export_skeleton(u, "c3d"))
    c = ezc3d.c3d(str(tmp_path / "x.c3d"))
    assert c["parameters"]["POINT"]["LABELS"]["value"][:25] == list(KINECT_V2.joints)
    assert c["parameters"]["POINT"]["RATE"]["value"][0] == pytest.approx(30.0)
    mc = read_c3d(tmp_path / "x.c3d")
    np.testing.assert_allclose(mc.positions, u.positions, atol=1e-5, equal_nan=True)
    (tmp_path / "x.trc").write_bytes(export_skeleton(u, "trc"))
    mt = read_trc(tmp_path / "x.trc")
    assert mt.labels == list(KINECT_V2.joints) and mt.rate == pytest.approx(30.0)
    np.testing.assert_allclose(mt.positions, u.positions, atol=1e-5, equal_nan=True)


def _recording_row(client: TestClient) -> None:
    """Project → subject → session → complete recording "R1" (the row the Record page
    makes), for the tests that attach to or export a recording."""
    from app.db import data as m

    p = client.post("/api/projects", json={"name": "S"}).json()
    s = client.post("/api/subjects", json={"project_id": p["id"], "code": "A1"}).json()
    sess = client.post("/api/sessions", json={"subject_id": s["id"]}).json()
    with client.app.state.db_sessions() as db:  # type: ignore[attr-defined]
        db.add(m.Recording(id="R1", session_id=sess["id"], state="complete", streams=""))
        db.commit()


def test_reference_upload_is_bounded(client: TestClient, tmp_path: Path,
                                     monkeypatch: pytest.MonkeyPatch) -> None:
    _recording_row(client)
    monkeypatch.setattr(_reference, "MAX_REFERENCE_BYTES", 1000)
    r = client.post("/api/exports/R1/references", files={"file": ("big.csv", b"x" * 5000)})
    assert r.status_code == 413 and "larger" in r.json()["detail"]
    assert not any((tmp_path / "references" / "R1").iterdir())
    r = client.post("/api/exports/R1/references", files={"file": ("bad.csv", b"a,b\n1,2\n")})
    assert r.status_code == 400 and "not a readable CSV" in r.json()["detail"]
    r = client.get("/api/exports/R1/skeleton", params={"source": "../etc"})
    assert r.status_code == 400 and "sensor id" in r.json()["detail"]


def _calibrate(data_dir: Path, yaw: float) -> int:
    """Save a calibration of sensor S1 (the newest version is the active one)."""
    from app.server import calibration as cal
    from engine.calibration.pipeline import CalibrationResult

    c, s_ = np.cos(yaw), np.sin(yaw)
    T = np.array([[c, -s_, 0, 1.0], [s_, c, 0, -2.0], [0, 0, 1, 0.8], [0, 0, 0, 1]])
    res = CalibrationResult(T_world_sensor={"S1": T}, T_world_sensor_chained={"S1": T},
                            T_world_marker={1: np.eye(4)}, marker_sizes={1: 0.4},
                            sensor_residual_m={"S1": 0.002}, edges=[], observations=[])
    return cal.save(data_dir, res)


def test_fused_export_keeps_the_recordings_own_poses(client: TestClient, tmp_path: Path
                                                     ) -> None:
    """A recalibration after the recording does not change its fused export."""
    _make_part(tmp_path / "node-side", server=tmp_path)
    _recording_row(client)
    r = client.get("/api/exports/R1/skeleton", params={"format": "csv", "source": "fused"})
    assert r.status_code == 400 and "sensor S1 has no calibrated pose" in r.json()["detail"]
    first = _calibrate(tmp_path, 0.3)
    before = client.get("/api/exports/R1/skeleton", params={"format": "csv", "source": "fused"})
    assert before.status_code == 200, before.text
    snap = (tmp_path / "recordings" / "R1" / "sensors.json").read_text()
    assert json.loads(snap)["S1"]["calibration_version"] == str(first)
    # the rig is calibrated again (another pose for S1); the old recording keeps its own
    assert _calibrate(tmp_path, 1.2) != first
    after = client.get("/api/exports/R1/skeleton", params={"format": "csv", "source": "fused"})
    assert after.content == before.content
    assert (tmp_path / "recordings" / "R1" / "sensors.json").read_text() == snap
    # a recording made after the recalibration would use the new pose (the snapshot is
    # what differs): removing the snapshot changes the export
    (tmp_path / "recordings" / "R1" / "sensors.json").unlink()
    again = client.get("/api/exports/R1/skeleton", params={"format": "csv", "source": "fused"})
    assert again.status_code == 200 and again.content != before.content
