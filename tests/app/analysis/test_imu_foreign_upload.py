"""IMU upload of other labs' files: reference quaternion columns in NED, scalar last
(``quat_order``/``quat_frame`` in the form when gravity cannot tell), and dropped samples
filled before filtering — the session's reference error is the BROAD trial's own."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from engine.imu.io import ImuRecording
from tests.app.analysis.test_imu_api import client  # noqa: F401 - the logged-in fixture
from tests.engine.imu.test_foreign_imu import (  # noqa: F401 - fixtures
    DEG,
    _to_ned,
    base,
    errors,
    truth,
    write_csv,
    xyz_lower,
)


def _post(c: TestClient, content: bytes, **data: object) -> tuple[int, dict]:
    r = c.post("/api/imu/sessions", files=[("files", ("lab.csv", content, "text/csv"))],
               data={"synchronise": "false", **data})
    return r.status_code, r.json()


def test_reference_in_ned_with_declared_conventions(client: TestClient,  # noqa: F811
                                                    base: ImuRecording,  # noqa: F811
                                                    truth: dict,  # noqa: F811
                                                    tmp_path: Path) -> None:
    assert base.quat_ref is not None
    q = _to_ned(base.quat_ref)[:, [1, 2, 3, 0]]  # scalar last, NED
    cols = [("time", base.time), *xyz_lower("acc_{}", base.acc),
            *xyz_lower("gyr_{}", base.gyr, DEG), *xyz_lower("mag_{}", base.mag),
            *[(f"q{k + 1}", q[:, k]) for k in range(4)]]
    content = write_csv(tmp_path / "lab.csv", cols).read_bytes()
    code, body = _post(client, content, quat_order="xyzw", quat_frame="NED")
    assert code == 200, body
    ref = body["reference_errors"]["lab"]
    # the filter's error against the file's reference is the one against BROAD's own
    # (the page's filter runs on the whole 60 s, the movement mask is not in the file)
    own = errors(base, base.quat_ref, None)
    assert ref["total_deg"] == pytest.approx(own["total_deg"], abs=0.05)
    code, body = _post(client, content, quat_frame="Z-down")
    assert code == 422


def test_dropped_samples_are_filled_on_upload(client: TestClient,  # noqa: F811
                                              base: ImuRecording,  # noqa: F811
                                              tmp_path: Path) -> None:
    assert base.quat_ref is not None and base.mag is not None
    keep = np.ones(len(base), bool)
    for s in np.random.default_rng(0).choice(len(base) - 10, len(base) // 500,
                                             replace=False):
        keep[s:s + 5] = False
    cols = [("time", base.time[keep]), *xyz_lower("acc_{}", base.acc[keep]),
            *xyz_lower("gyr_{}", base.gyr[keep], DEG), *xyz_lower("mag_{}", base.mag[keep]),
            *[(f"q{k}", base.quat_ref[keep, k]) for k in range(4)]]
    code, body = _post(client, write_csv(tmp_path / "lab.csv", cols).read_bytes())
    assert code == 200, body
    (row,) = body["sensors"]
    assert row["samples"] == len(base)
    assert any(re.match(r"\d+ dropped samples filled", w) for w in row["warnings"])
    own = errors(base, base.quat_ref, None)
    assert body["reference_errors"]["lab"]["total_deg"] == pytest.approx(
        own["total_deg"], abs=0.1)


def test_apdm_file_with_two_sensors(client: TestClient, base: ImuRecording,  # noqa: F811
                                    tmp_path: Path) -> None:
    from dataclasses import replace

    from tests.engine.imu.test_foreign_imu import write_apdm

    p = write_apdm(tmp_path / "opal.h5", {"XI-010284": ("Lumbar", base),
                                          "XI-010301": ("Foot", replace(base, quat_ref=None))})
    content = p.read_bytes()
    r = client.post("/api/imu/sessions", files=[("files", ("opal.h5", content, "x/h5"))],
                    data={"synchronise": "false"})
    assert r.status_code == 400
    assert "XI-010284 (Lumbar), XI-010301 (Foot)" in r.json()["detail"]
    r = client.post("/api/imu/sessions", files=[("files", ("opal.h5", content, "x/h5"))],
                    data={"synchronise": "false", "file_sensors": "XI-010284"})
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["sensors"][0]["name"] == "opal_XI-010284"
    assert "opal_XI-010284" in (body["reference_errors"] or {})
