"""IMU upload of a CSV holding several sensors (two Shimmers in one Consensys export):
refused with the list of its sensors until one is chosen in ``file_sensors``; the same
file uploaded twice gives two of its sensors."""

from __future__ import annotations

from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from engine.imu.io import ImuRecording
from tests.app.analysis.test_imu_api import client  # noqa: F401 - the logged-in fixture
from tests.engine.imu.test_imu_devices import _shimmer, recs  # noqa: F401 - fixture


@pytest.fixture
def two(recs: tuple[ImuRecording, ImuRecording], tmp_path: Path) -> bytes:  # noqa: F811
    a, b = recs
    return _shimmer(tmp_path / "two.csv", {"8C4F": a, "9A1B": b}).read_bytes()


def _upload(c: TestClient, content: bytes, n: int = 1, **data: object) -> tuple[int, dict]:
    files = [("files", ("two.csv", content, "text/csv")) for _ in range(n)]
    r = c.post("/api/imu/sessions", files=files, data=data)
    return r.status_code, r.json()


def test_several_sensors_in_a_file_need_a_choice(client: TestClient,  # noqa: F811
                                                  two: bytes) -> None:
    code, body = _upload(client, two)
    assert code == 400
    msg = body["detail"]
    assert msg.startswith("two.csv: the file holds 2 sensors (Shimmer_8C4F, Shimmer_9A1B)")
    assert "file_sensors" in msg and "gaitrig-imu" not in msg and "imu0" not in msg
    code, body = _upload(client, two, file_sensors="FFFF")
    assert code == 400 and "no sensor 'FFFF'" in body["detail"]
    code, body = _upload(client, two, file_sensors="../x")
    assert code == 400 and "sensor in file" in body["detail"]


def test_the_chosen_sensor_is_read(client: TestClient, two: bytes,  # noqa: F811
                                   recs: tuple[ImuRecording, ImuRecording]) -> None:  # noqa: F811
    code, body = _upload(client, two, file_sensors="9A1B")
    assert code == 200, body
    (row,) = body["sensors"]
    assert row["samples"] == len(recs[1]) and row["magnetometer"]
    ignored = next(w for w in row["warnings"] if w.startswith("ignored"))
    assert "Shimmer_8C4F_Gyro_X_CAL" in ignored and "Shimmer_9A1B_Gyro_X" not in ignored


def test_one_file_twice_gives_two_of_its_sensors(client: TestClient,  # noqa: F811
                                                 two: bytes) -> None:
    code, body = _upload(client, two, n=2, sensors=["thigh_l", "shank_l"],
                         file_sensors=["Shimmer_8C4F", "Shimmer_9A1B"])
    assert code == 200, body
    assert [s["name"] for s in body["sensors"]] == ["thigh_l", "shank_l"]
    # without names, each is named after the file and its sensor
    code, body = _upload(client, two, n=2, file_sensors=["8C4F", "9A1B"])
    assert code == 200, body
    assert [s["name"] for s in body["sensors"]] == ["two_8C4F", "two_9A1B"]
    code, body = _upload(client, two, n=2, file_sensors=["8C4F", "9A1B", "8C4F"])
    assert code == 400 and "one sensor-in-file choice per file" in body["detail"]
