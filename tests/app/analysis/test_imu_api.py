"""IMU page API in-process: uploads (real x-IMU data, bad files, generic CSV with unit
mistakes), a fused session from a skeleton CSV, the simulated session against ground truth."""

from __future__ import annotations

import csv
import io
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    s = Settings(data_dir=tmp_path, viewer_enabled=False, node_token="imu-test-token",
                 admin_password="imu-pw")
    with TestClient(create_app(s)) as c:
        r = c.post("/api/auth/login", json={"username": "admin", "password": "imu-pw"})
        c.headers["Authorization"] = f"Bearer {r.json()['token']}"
        yield c


def test_needs_login(tmp_path: Path) -> None:
    s = Settings(data_dir=tmp_path, viewer_enabled=False, admin_password="imu-pw")
    with TestClient(create_app(s)) as c:
        assert c.post("/api/imu/simulate", json={}).status_code == 401


def test_upload_madgwick_example_data(client: TestClient, shared_data: Path) -> None:
    mat = shared_data / "imu" / "madgwick" / "ExampleData.mat"
    for filt in ("madgwick", "ours"):
        with mat.open("rb") as fh:
            r = client.post("/api/imu/sessions",
                            files={"files": ("ExampleData.mat", fh, "application/octet-stream")},
                            data={"filter": filt, "beta": "0.041"})
        assert r.status_code == 200, r.text
        d = r.json()
        assert d["kind"] == "imu_only" and d["filter"] == filt
        (sensor,) = d["sensors"]
        assert sensor["name"] == "ExampleData" and sensor["samples"] == 6959
        assert sensor["frequency_hz"] == pytest.approx(256.0, abs=0.5)
        assert sensor["magnetometer"] is True
        png = client.get(d["plots"]["orientation"])
        assert png.status_code == 200 and png.content[:8] == b"\x89PNG\r\n\x1a\n"
        text = client.get(d["csv_url"]).text
        rows = list(csv.reader(io.StringIO(text)))
        assert rows[0][:2] == ["sensor_time_s", "ExampleData_qw"]
        assert len(rows) == 6960
        q = np.array(rows[100][1:5], dtype=float)
        assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-3)
    # the two filters give different but close orientations once settled
    assert client.get(f"/api/imu/sessions/{d['id']}").json()["id"] == d["id"]


def test_upload_broad_trial_against_its_optical_reference(client: TestClient,
                                                          shared_data: Path) -> None:
    trial = shared_data / "imu" / "broad" / "07_undisturbed_fast_rotation_B.hdf5"
    err = {}
    for filt in ("madgwick", "ours"):
        with trial.open("rb") as fh:
            r = client.post("/api/imu/sessions", data={"filter": filt, "sensors": "wrist"},
                            files={"files": (trial.name, fh, "application/octet-stream")})
        assert r.status_code == 200, r.text
        d = r.json()
        assert d["sensors"][0]["name"] == "wrist" and d["sensors"][0]["format"] == "broad"
        err[filt] = d["reference_errors"]["wrist"]
    # BROAD error measure on real data: both plausible, ours clearly better than β = 0.041
    assert err["madgwick"]["total_deg"] < 15.0
    assert err["ours"]["total_deg"] < 0.5 * err["madgwick"]["total_deg"]
    assert err["ours"]["inclination_deg"] < err["madgwick"]["inclination_deg"]


def test_bad_files_give_clear_400(client: TestClient, tmp_path: Path) -> None:
    r = client.post("/api/imu/sessions", files={"files": ("notes.docx", b"xx", "text/plain")})
    assert r.status_code == 400 and "unsupported type .docx" in r.json()["detail"]
    r = client.post("/api/imu/sessions", files={"files": ("bad.mat", b"not a mat file", "x")})
    assert r.status_code == 400 and "bad.mat" in r.json()["detail"]
    assert "gaitrig-imu" not in r.json()["detail"]  # no server temp paths shown
    # a truncated .mat: the engine's typed error (not the route's catch-all) names it
    import scipy.io

    mat = tmp_path / "whole.mat"
    scipy.io.savemat(mat, {"time": np.zeros((50, 1)), "Gyroscope": np.zeros((50, 3)),
                           "Accelerometer": np.zeros((50, 3))}, do_compression=True)
    r = client.post("/api/imu/sessions",
                    files={"files": ("trial.mat", mat.read_bytes()[:300], "x")})
    assert r.status_code == 400
    assert r.json()["detail"].startswith("trial.mat: not a readable MATLAB .mat file")
    assert "export it again" in r.json()["detail"]
    # generic CSV without declared units
    t = np.arange(200) / 100
    rows = ["time,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z"]
    rows += [f"{ti},0.01,0,0,0,0,1.0" for ti in t]  # acc in g
    data = "\n".join(rows).encode()
    r = client.post("/api/imu/sessions", files={"files": ("mine.csv", data, "text/csv")})
    assert r.status_code == 400 and "declared units" in r.json()["detail"]
    # declared m/s² but the numbers are in g: the unit mistake is named
    r = client.post("/api/imu/sessions", files={"files": ("mine.csv", data, "text/csv")},
                    data={"gyr_unit": "rad/s", "acc_unit": "m/s2"})
    assert r.status_code == 400
    assert "probably in g" in r.json()["detail"] and "mine" in r.json()["detail"]
    # right units: accepted; NaN samples become a plain-words warning
    rows[50] = "0.49,nan,nan,nan,0,0,1.0"
    r = client.post("/api/imu/sessions",
                    files={"files": ("mine.csv", "\n".join(rows).encode(), "text/csv")},
                    data={"gyr_unit": "rad/s", "acc_unit": "g"})
    assert r.status_code == 200, r.text
    assert any("NaN" in w for w in r.json()["warnings"])
    # a skeleton needs sensors named after bones
    r = client.post("/api/imu/sessions",
                    files=[("files", ("mine.csv", "\n".join(rows).encode(), "text/csv")),
                           ("skeleton", ("walk.csv", b"time,SpineBase_x\n0,0\n", "text/csv"))],
                    data={"gyr_unit": "rad/s", "acc_unit": "g"})
    assert r.status_code == 400
    assert client.get("/api/imu/sessions/0123456789abcdef").status_code == 404
    assert client.get("/api/imu/sessions/..%2F..%2Fetc/data.csv").status_code == 404


def test_simulated_session_fused_beats_depth(client: TestClient) -> None:
    r = client.post("/api/imu/simulate", json={"filter": "ours"})
    assert r.status_code == 200, r.text
    d = r.json()
    assert d["kind"] == "fused" and d["source"] == "simulation"
    for j in ("knee_left", "knee_right", "elbow_left", "elbow_right"):
        acc = d["accuracy"][j]
        assert acc["fused_rmse_deg"] < 0.5 * acc["depth_rmse_deg"], (j, acc)
    # jump sync recovered the simulated IMU clock offsets (±2 s) to a few ms
    assert max(d["sync_error_ms"].values()) < 10.0
    assert len(d["sync"]) == 10  # nine IMUs + the skeleton
    assert set(d["plots"]) == {"sync", "angles"}
    assert client.get(d["plots"]["angles"]).content[:4] == b"\x89PNG"
    lines = client.get(d["csv_url"]).text.splitlines()
    assert lines[0].startswith("time_s,knee_left_fused_deg,knee_left_depth_deg")
    assert len(lines) > 1000


def test_fused_upload_from_files(client: TestClient, tmp_path: Path) -> None:
    """The simulated session written as files (generic CSVs + skeleton CSV) and uploaded."""
    from app.server.imu_analysis import simulate_session
    from engine.io.csv import write_skeleton_csv

    sim = simulate_session(seed=1)
    files = []
    for name, rec in sim["recordings"].items():
        buf = io.StringIO()
        buf.write("time,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z\n")
        np.savetxt(buf, np.column_stack([rec.time, np.degrees(rec.gyr), rec.acc, rec.mag]),
                   delimiter=",", fmt="%.6f")
        files.append(("files", (f"{name}.csv", buf.getvalue().encode(), "text/csv")))
    write_skeleton_csv(tmp_path / "depth.csv", sim["depth"])
    files.append(("skeleton", ("depth.csv", (tmp_path / "depth.csv").read_bytes(), "text/csv")))
    r = client.post("/api/imu/sessions", files=files,
                    data={"gyr_unit": "deg/s", "acc_unit": "m/s2", "mag_unit": "uT",
                          "filter": "madgwick", "beta": "0.1"})
    assert r.status_code == 200, r.text
    d = r.json()
    assert d["kind"] == "fused" and d["filter"] == "madgwick"
    offs = {row["stream"]: row["offset_s"] for row in d["sync"]}
    for n, off in sim["true_offsets"].items():
        assert offs[n] == pytest.approx(off, abs=0.01)
    assert d["angles"]["knee_left"]["depth_vs_fused_rmse_deg"] is not None


def test_depth_skeleton_from_a_recording(client: TestClient, tmp_path: Path) -> None:
    """The depth skeleton taken from a recording on the server (one sensor's part, sensor
    frame, placed in the world by the recording's sensor pose)."""
    import json

    from app.nodes.protocol import encode_skeletons
    from app.nodes.store import NodeStore
    from app.server.imu_analysis import simulate_session
    from engine.coverage import sensor_pose

    sim = simulate_session(seed=2)
    depth = sim["depth"]
    T = sensor_pose((8.0, 0.3, 1.0), 180.0)  # looking back along the walkway
    Ti = np.linalg.inv(T)
    rec_id = "R20260102-101500-0001"
    data_dir = client.app.state.settings.data_dir  # type: ignore[attr-defined]
    rec_dir = data_dir / "recordings" / rec_id
    w = NodeStore(rec_dir).create_part("S3", t_start_server=float(depth.times[0]))
    for k, t in enumerate(depth.times):
        P = depth.positions[k] @ Ti[:3, :3].T + Ti[:3, 3]
        w.append(float(t), "skeleton", encode_skeletons(k, float(t), P[None],
                                                        depth.states[k][None]))
    w.close()
    (rec_dir / "sensors.json").write_text(json.dumps({"S3": {"T_world_sensor": T.tolist()}}))
    assert client.get("/api/imu/recordings").json() == [{"id": rec_id, "sensors": ["S3"]}]
    names = ("chest", "thigh_l", "shank_l")
    files = []
    for name in names:
        rec = sim["recordings"][name]
        buf = io.StringIO()
        buf.write("time,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z\n")
        np.savetxt(buf, np.column_stack([rec.time, rec.gyr, rec.acc, rec.mag]), delimiter=",",
                   fmt="%.6f")
        files.append(("files", (f"{name}.csv", buf.getvalue().encode(), "text/csv")))
    units = {"gyr_unit": "rad/s", "acc_unit": "m/s2", "mag_unit": "uT"}
    r = client.post("/api/imu/sessions", files=files,
                    data={**units, "recording": rec_id, "recording_node": "S9"})
    assert r.status_code == 400 and "S3" in r.json()["detail"]
    r = client.post("/api/imu/sessions", files=files,
                    data={**units, "recording": "../../etc", "recording_node": "S3"})
    assert r.status_code == 400
    r = client.post("/api/imu/sessions", files=files,
                    data={**units, "recording": rec_id, "recording_node": "S3"})
    assert r.status_code == 200, r.text
    d = r.json()
    assert d["kind"] == "fused" and d["skeleton"]["frames"] == len(depth)
    offs = {row["stream"]: row["offset_s"] for row in d["sync"]}
    for n in names:
        assert offs[n] == pytest.approx(sim["true_offsets"][n], abs=0.01)
    assert d["angles"]["knee_left"]["fused_range_deg"] is not None
